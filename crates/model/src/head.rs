//! The head (SPEC §6–7, VarStore `head.`): fused features → 1x1 conv + ReLU + Dropout2d →
//! 1x1 conv to the 2K ordinal logits or, for the regression heads, one depth channel.

use std::rc::Rc;

use tch::Tensor;

use crate::layers::{Conv, MacRows, P};
use crate::sync_bn::{feature_dropout, DropoutSeeds, TrainHooks};
use depthsense_config::{HeadKind, ModelConfig};

/// The two 1x1 convs `head.conv1` and `head.conv2`.
pub(crate) struct Head {
    conv1: Conv,
    conv2: Conv,
    /// Per-sample dropout seeds of data-parallel training (`crate::sync_bn`), if any.
    seeds: Option<Rc<DropoutSeeds>>,
}

impl Head {
    /// The head of `cfg` under `root`, taking `fused` input channels.
    pub(crate) fn new(root: &P, fused: i64, cfg: &ModelConfig, hooks: &TrainHooks) -> Head {
        let h = root.sub("head");
        let conv1 = Conv::new(&h.sub("conv1"), fused, cfg.head_channels, 1, 1, 0, 1, true);
        let conv2 = Conv::new(
            &h.sub("conv2"),
            cfg.head_channels,
            cfg.head_out_channels(),
            1,
            1,
            0,
            1,
            true,
        );
        Head {
            conv1,
            conv2,
            seeds: hooks.dropout_seeds.clone(),
        }
    }

    /// Fused features `[B,C,h,w]` → `[B,2K,h,w]` ordinal logits or `[B,1,h,w]` depth in
    /// metres (see [`crate::DepthNet::forward_logits_t`]).
    pub(crate) fn forward_t(&self, f: Tensor, cfg: &ModelConfig, train: bool) -> Tensor {
        let seeds = self.seeds.as_deref();
        let mut f = f;
        if cfg.head_pre_dropout {
            f = feature_dropout(&f, cfg.dropout, train, seeds);
        }
        let y = feature_dropout(&self.conv1.forward(&f).relu(), cfg.dropout, train, seeds);
        let y = self.conv2.forward(&y);
        match cfg.head {
            HeadKind::Ordinal => y,
            // Regression heads: depth in metres, bounded to (0, β).
            HeadKind::L1 | HeadKind::L2 => y.sigmoid() * cfg.sid.beta_m,
        }
    }

    /// Multiply-adds of both convs at `hw`.
    pub(crate) fn count(&self, hw: (i64, i64), rows: &mut MacRows) {
        let o = self.conv1.count(hw, rows);
        self.conv2.count(o, rows);
    }
}
