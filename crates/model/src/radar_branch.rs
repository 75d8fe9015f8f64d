//! The radar branch of late fusion (SPEC §6 / §6.1, VarStore `radar.`), the high-resolution
//! radar path (`radar_skip.`) and the nearest-depth pooling that brings radar maps to a
//! coarser grid (SPEC §5: nearest wins).

use crate::sync_bn::TrainHooks;
use tch::Tensor;

use crate::encoder::{BlockKind, ResNet, ResNetSpec};
use crate::layers::{hw_of, resize_to, Conv, MacRows, P};
use depthsense_config::{ModelConfig, RadarBranchKind, StemKind};

/// Nearest non-zero depth of each `s`×`s` cell of `[B,C,H,W]` depth maps (0 = none):
/// max-pool of 1/d over the cell (0 stays 0), then back to metres. Identity for s ≤ 1.
pub(crate) fn nearest_depth_pool(depth_m: &Tensor, s: i64) -> Tensor {
    if s <= 1 {
        return depth_m.shallow_clone();
    }
    pool_nearest(depth_m, [s, s], false)
}

/// [`nearest_depth_pool`] to exactly `hw`: cells of ⌈H/h⌉×⌈W/w⌉ (ceil mode), then a nearest
/// resize if the conv arithmetic of the decoder rounded differently.
fn nearest_depth_pool_to(depth_m: &Tensor, hw: (i64, i64)) -> Tensor {
    let (hi, wi) = hw_of(depth_m);
    let k = [(hi + hw.0 - 1) / hw.0.max(1), (wi + hw.1 - 1) / hw.1.max(1)];
    resize_to(&pool_nearest(depth_m, k, true), hw, true)
}

/// The nearest non-zero depth of each `k` cell (stride = k): max-pool of 1/d.
fn pool_nearest(depth_m: &Tensor, k: [i64; 2], ceil_mode: bool) -> Tensor {
    let valid = depth_m.gt(0.0).to_kind(depth_m.kind());
    let inv = depth_m.clamp_min(1e-6).reciprocal() * valid;
    let inv_s = inv.max_pool2d(k, k, [0, 0], [1, 1], ceil_mode);
    inv_s.clamp_min(1e-12).reciprocal() * inv_s.gt(0.0).to_kind(inv_s.kind())
}

/// Radar branch of late fusion (SPEC §6 / §6.1).
pub(crate) struct RadarBranch {
    resnet: ResNet,
    /// Released `conv_radar.0` / `conv_radar.2` 1x1(b) + ReLU.
    post: Option<[Conv; 2]>,
    pub(crate) out_channels: i64,
}

impl RadarBranch {
    /// Folds its ResNet's BatchNorms for the inference graph.
    pub(crate) fn fold_batch_norm(&self, layout: crate::precision::InferenceLayout) {
        self.resnet.fold_batch_norm(layout);
    }

    pub(crate) fn new(p: &P, cfg: &ModelConfig, hooks: &TrainHooks) -> RadarBranch {
        let r = p.sub("radar");
        match cfg.radar_branch {
            RadarBranchKind::Basic => {
                let spec = ResNetSpec::standard(
                    18,
                    cfg.radar_channels,
                    cfg.radar_width,
                    StemKind::Torchvision,
                );
                let resnet = ResNet::new(&r, &spec, hooks.batch_norm.as_ref());
                let out_channels = resnet.channels[3];
                RadarBranch {
                    resnet,
                    post: None,
                    out_channels,
                }
            }
            RadarBranchKind::Bottleneck => {
                let spec = ResNetSpec {
                    in_channels: cfg.radar_channels,
                    width: cfg.radar_width,
                    stem: StemKind::Radar,
                    block: BlockKind::Bottleneck,
                    blocks: [2, 2, 2, 2],
                    strides: [1, 2, 1, 1],
                    dilations: [1, 1, 2, 4],
                };
                let resnet = ResNet::new(&r, &spec, hooks.batch_norm.as_ref());
                let c = resnet.channels[3];
                let o = cfg.radar_out_channels;
                let cr = r.sub("conv_radar");
                let post = [
                    Conv::new(&cr.sub("0"), c, o, 1, 1, 0, 1, true),
                    Conv::new(&cr.sub("2"), o, o, 1, 1, 0, 1, true),
                ];
                RadarBranch {
                    resnet,
                    post: Some(post),
                    out_channels: o,
                }
            }
        }
    }

    /// `[B,C,H,W]` scaled radar → `[B,out,H/32,W/32]`.
    pub(crate) fn forward_t(&self, x: &Tensor, train: bool) -> Tensor {
        let mut y = self.resnet.forward_t(x, train).pop().expect("4 levels");
        if let Some([a, b]) = &self.post {
            y = b.forward(&a.forward(&y).relu()).relu();
        }
        y
    }

    pub(crate) fn count(&self, hw: (i64, i64), rows: &mut MacRows) {
        let mut o = *self.resnet.count(hw, rows).last().expect("4 levels");
        if let Some([a, b]) = &self.post {
            o = a.count(o, rows);
            b.count(o, rows);
        }
    }
}

/// The high-resolution radar path (`radar_skip_channels` > 0, see [`ModelConfig`]): the radar
/// map at the head's resolution (nearest return per cell) → 3x3 conv + ReLU → 3x3 conv + ReLU.
pub(crate) struct RadarSkip {
    convs: [Conv; 2],
}

impl RadarSkip {
    pub(crate) fn new(p: &P, cin: i64, ch: i64) -> RadarSkip {
        let s = p.sub("radar_skip");
        RadarSkip {
            convs: [
                Conv::new(&s.sub("conv1"), cin, ch, 3, 1, 1, 1, true),
                Conv::new(&s.sub("conv2"), ch, ch, 3, 1, 1, 1, true),
            ],
        }
    }

    /// `[B,C,H,W]` scaled radar (any resolution) → `[B,ch,h,w]` at `hw`.
    pub(crate) fn forward(&self, radar: &Tensor, hw: (i64, i64)) -> Tensor {
        let r = nearest_depth_pool_to(radar, hw);
        self.convs[1]
            .forward(&self.convs[0].forward(&r).relu())
            .relu()
    }

    /// Output channels (`ch`).
    pub(crate) fn out_channels(&self) -> i64 {
        self.convs[1].out_channels()
    }

    pub(crate) fn count(&self, hw: (i64, i64), rows: &mut MacRows) {
        let o = self.convs[0].count(hw, rows);
        self.convs[1].count(o, rows);
    }
}

#[cfg(test)]
mod pool_tests {
    use super::*;

    #[test]
    fn nearest_depth_pool_keeps_the_nearest_return_of_each_cell() {
        // 1×1×2×4 map, cells of 2×2: {0, 5, 0, 7} → 5; {3, 0, 0, 0} → 3 (0 = none).
        let d = Tensor::from_slice(&[0.0f32, 5.0, 3.0, 0.0, 0.0, 7.0, 0.0, 0.0]).view([1, 1, 2, 4]);
        let p = nearest_depth_pool(&d, 2);
        assert_eq!(p.size(), [1, 1, 1, 2]);
        let v: Vec<f32> = Vec::try_from(p.reshape([-1])).unwrap();
        assert!(
            (v[0] - 5.0).abs() < 1e-4 && (v[1] - 3.0).abs() < 1e-4,
            "{v:?}"
        );
        assert_eq!(nearest_depth_pool(&d, 1).size(), [1, 1, 2, 4]);
    }

    #[test]
    fn nearest_depth_pool_to_reaches_the_decoder_size_with_ceil_cells() {
        // 5×9 map to 2×3: cells of 3×3 (ceil), the last row/column cells partial.
        let mut v = vec![0.0f32; 45];
        v[4 * 9 + 8] = 20.0; // bottom-right corner, in the partial cell (1, 2)
        v[0] = 9.0;
        v[1] = 4.0; // cell (0, 0): nearest = 4
        let d = Tensor::from_slice(&v).view([1, 1, 5, 9]);
        let p = nearest_depth_pool_to(&d, (2, 3));
        let got: Vec<f32> = Vec::try_from(p.reshape([-1])).unwrap();
        let want = [4.0, 0.0, 0.0, 0.0, 0.0, 20.0];
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() < 1e-3, "{got:?}");
        }
    }
}
