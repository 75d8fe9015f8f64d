//! Fusion of camera and radar (SPEC §6): early fusion (the scaled radar map as extra input
//! channels of the RGB encoder), late fusion (the radar branch's features, and those of the
//! high-resolution radar path, concatenated to the decoder's) and the CBAM spatial attention
//! over the fused features (VarStore `attention.`).

use tch::Tensor;

use crate::layers::{hw_of, resize_to, Conv, ConvInit, MacRows, P};
use crate::radar_branch::{RadarBranch, RadarSkip};
use depthsense_config::{AttentionGate, Fusion, ModelConfig};

/// Input channels of the RGB encoder: the image's 3, plus the radar's with early fusion.
pub(crate) fn encoder_in_channels(cfg: &ModelConfig) -> i64 {
    3 + if cfg.fusion == Fusion::Early {
        cfg.radar_channels
    } else {
        0
    }
}

/// The factor on the radar depth the network sees.
pub(crate) fn radar_scale(cfg: &ModelConfig) -> f64 {
    // The network sees radar depth scaled by 1/β (the caller passes metres), or in metres
    // as the authors' code feeds it (`radar_in_metres`, released).
    if cfg.radar_in_metres {
        1.0
    } else {
        1.0 / cfg.sid.beta_m
    }
}

/// The RGB encoder's input: with early fusion the image and the scaled radar concatenated
/// along channels, else the image alone.
pub(crate) fn encoder_input(
    cfg: &ModelConfig,
    image: &Tensor,
    radar_scaled: &dyn Fn() -> Tensor,
) -> Tensor {
    match cfg.fusion {
        Fusion::Early => Tensor::cat(&[image.shallow_clone(), radar_scaled()], 1),
        _ => image.shallow_clone(),
    }
}

/// Late fusion: the radar branch (`radar.`) and, with `radar_skip_channels` > 0, the
/// high-resolution radar path (`radar_skip.`), whose features join the decoder's.
pub(crate) struct LateFusion {
    radar: RadarBranch,
    skip: Option<RadarSkip>,
}

impl LateFusion {
    /// Folds the radar branch's BatchNorms for the inference graph (the radar skip has none).
    pub(crate) fn fold_batch_norm(&self, layout: crate::precision::InferenceLayout) {
        self.radar.fold_batch_norm(layout);
    }

    /// The radar paths of `cfg` under `root` (in this order), or `None` without late fusion.
    pub(crate) fn new(
        root: &P,
        cfg: &ModelConfig,
        hooks: &crate::sync_bn::TrainHooks,
    ) -> Option<LateFusion> {
        let radar = (cfg.fusion == Fusion::Late).then(|| RadarBranch::new(root, cfg, hooks))?;
        let skip_ch = cfg.radar_skip_channels;
        let skip = (skip_ch > 0).then(|| RadarSkip::new(root, cfg.radar_channels, skip_ch));
        Some(LateFusion { radar, skip })
    }

    /// Channels added to the decoder's: the radar branch's, plus the radar path's.
    pub(crate) fn out_channels(&self) -> i64 {
        self.radar.out_channels + self.skip.as_ref().map_or(0, RadarSkip::out_channels)
    }

    /// Decoder features `f` `[B,C,h,w]` → `[B,C+out,h,w]`: the radar branch's output (shown
    /// to `tap` as `radar`, then resized to h×w) and the radar path's (`radar_skip`)
    /// concatenated after `f`.
    pub(crate) fn forward_t(
        &self,
        f: Tensor,
        radar_scaled: &dyn Fn() -> Tensor,
        train: bool,
        tap: &mut dyn FnMut(&str, &Tensor),
    ) -> Tensor {
        let rf = self.radar.forward_t(&radar_scaled(), train);
        tap("radar", &rf);
        let r = resize_to(&rf, hw_of(&f), false);
        let mut f = Tensor::cat(&[f, r], 1);
        if let Some(skip) = &self.skip {
            let s = skip.forward(&radar_scaled(), hw_of(&f));
            tap("radar_skip", &s);
            f = Tensor::cat(&[f, s], 1);
        }
        f
    }

    /// Multiply-adds of the radar branch for an `input_hw` radar map, then of the radar path
    /// at the head resolution `head_hw`.
    pub(crate) fn count(&self, input_hw: (i64, i64), head_hw: (i64, i64), rows: &mut MacRows) {
        self.radar.count(input_hw, rows);
        if let Some(s) = &self.skip {
            s.count(head_hw, rows);
        }
    }
}

/// The spatial attention module (SPEC §6, CBAM): `[B,C,h,w]` → `[B,C,h,w]`, the features
/// times a per-pixel gate from [mean, max] over channels → 7x7 conv.
///
/// The gate is [`ModelConfig::attention_gate`]: ½ + σ(s) in the presets (cannot switch the
/// features off), or 2σ(s) (the paper's σ(s) times 2, which the linear 1x1 head absorbs).
/// With the conv starting at zero both start as the identity instead of halving (σ(0) = ½)
/// or, with a random conv, saturating the features.
pub(crate) struct SpatialAttention {
    conv: Conv,
    gate: AttentionGate,
}

impl SpatialAttention {
    /// The 7x7 conv `attention.conv` under `root`, starting at zero.
    pub(crate) fn new(root: &P, gate: AttentionGate) -> SpatialAttention {
        // SPEC §6: CBAM spatial attention, [mean, max] over channels → 7x7 conv → gate. The conv
        // starts at zero so that either gate starts as the identity (see `attend`).
        let conv = Conv::with_init(
            &root.sub("attention").sub("conv"),
            [2, 1, 7, 1, 3, 1],
            true,
            ConvInit::Zero,
        );
        SpatialAttention { conv, gate }
    }

    /// The gated features, shapes as `f`.
    pub(crate) fn forward(&self, f: &Tensor) -> Tensor {
        let mean = f.mean_dim(1, true, f.kind());
        let (max, _) = f.max_dim(1, true);
        let s = self.conv.forward(&Tensor::cat(&[mean, max], 1));
        match self.gate {
            AttentionGate::Double => f * (s.sigmoid() * 2.0),
            AttentionGate::Bounded => f * (s.sigmoid() + 0.5),
        }
    }

    /// Multiply-adds of the gate's conv at `hw`.
    pub(crate) fn count(&self, hw: (i64, i64), rows: &mut MacRows) {
        self.conv.count(hw, rows);
    }
}
