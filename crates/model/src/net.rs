//! The DepthSense network (SPEC §6): RGB encoder, decoder, radar branch, fusion, head.

use tch::{nn, Kind, Tensor};

use crate::config::{
    AttentionGate, DecoderKind, Fusion, HeadKind, ModelConfig, RadarBranchKind, StemKind,
};
use crate::layers::{BlockKind, Conv, ConvInit, MacRows, ResNet, ResNetSpec, P};
use crate::ordinal::{self, RegressionLoss};
use crate::ModelError;

/// Nearest non-zero depth of each `s`×`s` cell of `[B,C,H,W]` depth maps (0 = none):
/// max-pool of 1/d over the cell (0 stays 0), then back to metres. Identity for s ≤ 1.
fn nearest_depth_pool(depth_m: &Tensor, s: i64) -> Tensor {
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

fn resize_to(x: &Tensor, hw: (i64, i64), nearest: bool) -> Tensor {
    let (_, _, h, w) = x.size4().expect("4-d feature map");
    if (h, w) == hw {
        x.shallow_clone()
    } else if nearest {
        x.upsample_nearest2d([hw.0, hw.1], None, None)
    } else {
        x.upsample_bilinear2d([hw.0, hw.1], false, None, None)
    }
}

fn hw_of(x: &Tensor) -> (i64, i64) {
    let s = x.size();
    (s[s.len() - 2], s[s.len() - 1])
}

/// Image decoder over C2..C4 (SPEC §6).
#[allow(clippy::large_enum_variant)] // built once per network
enum Decoder {
    /// Paper: laterals 1x1(b) → ch, nearest ×2 top-down addition, 3x3(b) smoothing, the three
    /// levels upsampled (bilinear) to the finest (stride 8) and concatenated → 3·ch.
    Topdown {
        lateral: [Conv; 3],
        smooth: [Conv; 3],
    },
    /// Released (SPEC §6.1): FPN P3..P5 then `convfeat1` 7x7/4, `convfeat2` 3x3/2,
    /// `convfeat3` 3x3/1 + ReLU to stride 32, concatenated → 3·ch.
    Released {
        lateral: [Conv; 3],
        smooth: [Conv; 3],
        feat: [Conv; 3],
    },
}

impl Decoder {
    fn new(p: &P, kind: DecoderKind, cin: [i64; 3], ch: i64) -> Decoder {
        match kind {
            DecoderKind::Topdown => {
                let d = p.sub("decoder");
                let lat = |i: usize| {
                    Conv::new(
                        &d.sub(&format!("lateral{}", i + 2)),
                        cin[i],
                        ch,
                        1,
                        1,
                        0,
                        1,
                        true,
                    )
                };
                let sm = |i: usize| {
                    Conv::new(
                        &d.sub(&format!("smooth{}", i + 2)),
                        ch,
                        ch,
                        3,
                        1,
                        1,
                        1,
                        true,
                    )
                };
                Decoder::Topdown {
                    lateral: [lat(0), lat(1), lat(2)],
                    smooth: [sm(0), sm(1), sm(2)],
                }
            }
            DecoderKind::Released => {
                let d = p.sub("decoder");
                let f = d.sub("fpn");
                // P3 ← C2, P4 ← C3, P5 ← C4.
                let lat = |i: usize| {
                    Conv::new(
                        &f.sub(&format!("P{}_1", i + 3)),
                        cin[i],
                        ch,
                        1,
                        1,
                        0,
                        1,
                        true,
                    )
                };
                let sm = |i: usize| {
                    Conv::new(&f.sub(&format!("P{}_2", i + 3)), ch, ch, 3, 1, 1, 1, true)
                };
                let feat = [
                    Conv::new(&d.sub("convfeat1"), ch, ch, 7, 4, 2, 1, false),
                    Conv::new(&d.sub("convfeat2"), ch, ch, 3, 2, 1, 1, false),
                    Conv::new(&d.sub("convfeat3"), ch, ch, 3, 1, 1, 1, false),
                ];
                Decoder::Released {
                    lateral: [lat(0), lat(1), lat(2)],
                    smooth: [sm(0), sm(1), sm(2)],
                    feat,
                }
            }
        }
    }

    /// Top-down pyramid: [t2, t3, t4] after smoothing (finest first).
    fn pyramid(lateral: &[Conv; 3], smooth: &[Conv; 3], c: &[Tensor]) -> [Tensor; 3] {
        let t4 = lateral[2].forward(&c[3]);
        let t3 = lateral[1].forward(&c[2]) + resize_to(&t4, hw_of(&c[2]), true);
        let t2 = lateral[0].forward(&c[1]) + resize_to(&t3, hw_of(&c[1]), true);
        [
            smooth[0].forward(&t2),
            smooth[1].forward(&t3),
            smooth[2].forward(&t4),
        ]
    }

    /// C1..C4 → `[B,3·ch,h,w]` (h,w = C2's size for top-down, C4's for released).
    fn forward(&self, c: &[Tensor]) -> Tensor {
        match self {
            Decoder::Topdown { lateral, smooth } => {
                let [p2, p3, p4] = Self::pyramid(lateral, smooth, c);
                let hw = hw_of(&p2);
                Tensor::cat(
                    &[p2, resize_to(&p3, hw, false), resize_to(&p4, hw, false)],
                    1,
                )
            }
            Decoder::Released {
                lateral,
                smooth,
                feat,
            } => {
                let [p3, p4, p5] = Self::pyramid(lateral, smooth, c);
                let f3 = feat[2].forward(&p5).relu();
                let hw = hw_of(&f3);
                let f1 = resize_to(&feat[0].forward(&p3).relu(), hw, false);
                let f2 = resize_to(&feat[1].forward(&p4).relu(), hw, false);
                Tensor::cat(&[f1, f2, f3], 1)
            }
        }
    }

    fn count(&self, sizes: &[(i64, i64)], rows: &mut MacRows) -> (i64, i64) {
        let (lateral, smooth) = match self {
            Decoder::Topdown { lateral, smooth }
            | Decoder::Released {
                lateral, smooth, ..
            } => (lateral, smooth),
        };
        for i in 0..3 {
            let o = lateral[i].count(sizes[i + 1], rows);
            smooth[i].count(o, rows);
        }
        match self {
            Decoder::Topdown { .. } => sizes[1],
            Decoder::Released { feat, .. } => {
                feat[0].count(sizes[1], rows);
                feat[1].count(sizes[2], rows);
                feat[2].count(sizes[3], rows)
            }
        }
    }

    fn out_channels(&self) -> i64 {
        match self {
            Decoder::Topdown { smooth, .. } | Decoder::Released { smooth, .. } => {
                3 * smooth[0].out_channels()
            }
        }
    }
}

/// Radar branch of late fusion (SPEC §6 / §6.1).
struct RadarBranch {
    resnet: ResNet,
    /// Released `conv_radar.0` / `conv_radar.2` 1x1(b) + ReLU.
    post: Option<[Conv; 2]>,
    out_channels: i64,
}

impl RadarBranch {
    fn new(p: &P, cfg: &ModelConfig) -> RadarBranch {
        let r = p.sub("radar");
        match cfg.radar_branch {
            RadarBranchKind::Basic => {
                let spec = ResNetSpec::standard(
                    18,
                    cfg.radar_channels,
                    cfg.radar_width,
                    StemKind::Torchvision,
                );
                let resnet = ResNet::new(&r, &spec);
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
                let resnet = ResNet::new(&r, &spec);
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
    fn forward_t(&self, x: &Tensor, train: bool) -> Tensor {
        let mut y = self.resnet.forward_t(x, train).pop().expect("4 levels");
        if let Some([a, b]) = &self.post {
            y = b.forward(&a.forward(&y).relu()).relu();
        }
        y
    }

    fn count(&self, hw: (i64, i64), rows: &mut MacRows) {
        let mut o = *self.resnet.count(hw, rows).last().expect("4 levels");
        if let Some([a, b]) = &self.post {
            o = a.count(o, rows);
            b.count(o, rows);
        }
    }
}

/// The high-resolution radar path (`radar_skip_channels` > 0, see [`ModelConfig`]): the radar
/// map at the head's resolution (nearest return per cell) → 3x3 conv + ReLU → 3x3 conv + ReLU.
struct RadarSkip {
    convs: [Conv; 2],
}

impl RadarSkip {
    fn new(p: &P, cin: i64, ch: i64) -> RadarSkip {
        let s = p.sub("radar_skip");
        RadarSkip {
            convs: [
                Conv::new(&s.sub("conv1"), cin, ch, 3, 1, 1, 1, true),
                Conv::new(&s.sub("conv2"), ch, ch, 3, 1, 1, 1, true),
            ],
        }
    }

    /// `[B,C,H,W]` scaled radar (any resolution) → `[B,ch,h,w]` at `hw`.
    fn forward(&self, radar: &Tensor, hw: (i64, i64)) -> Tensor {
        let r = nearest_depth_pool_to(radar, hw);
        self.convs[1]
            .forward(&self.convs[0].forward(&r).relu())
            .relu()
    }

    fn count(&self, hw: (i64, i64), rows: &mut MacRows) {
        let o = self.convs[0].count(hw, rows);
        self.convs[1].count(o, rows);
    }
}

/// The DepthSense network. Build with [`DepthNet::new`]; variables live in the caller's
/// VarStore under `rgb.`, `decoder.`, `radar.`, `radar_skip.`, `attention.`, `head.`.
pub struct DepthNet {
    cfg: ModelConfig,
    rgb: ResNet,
    decoder: Decoder,
    radar: Option<RadarBranch>,
    radar_skip: Option<RadarSkip>,
    attention: Option<Conv>,
    head1: Conv,
    head2: Conv,
}

impl std::fmt::Debug for DepthNet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DepthNet")
            .field("config", &self.cfg)
            .finish_non_exhaustive()
    }
}

impl DepthNet {
    /// Creates the variables of `cfg` under `p` (usually `vs.root()`).
    pub fn new(p: &nn::Path, cfg: &ModelConfig) -> Result<DepthNet, ModelError> {
        cfg.validate()?;
        let root = P::root(p);
        let in_ch = 3 + if cfg.fusion == Fusion::Early {
            cfg.radar_channels
        } else {
            0
        };
        let spec = ResNetSpec::standard(cfg.backbone_depth, in_ch, cfg.backbone_width, cfg.stem);
        let rgb = ResNet::new(&root.sub("rgb"), &spec);
        let ch = rgb.channels;
        let decoder = Decoder::new(
            &root,
            cfg.decoder,
            [ch[1], ch[2], ch[3]],
            cfg.decoder_channels,
        );
        let radar = (cfg.fusion == Fusion::Late).then(|| RadarBranch::new(&root, cfg));
        let skip_ch = cfg.radar_skip_channels;
        let radar_skip = (cfg.fusion == Fusion::Late && skip_ch > 0)
            .then(|| RadarSkip::new(&root, cfg.radar_channels, skip_ch));
        let fused = decoder.out_channels()
            + radar.as_ref().map_or(0, |r| r.out_channels)
            + radar_skip.as_ref().map_or(0, |_| skip_ch);
        // SPEC §6: CBAM spatial attention, [mean, max] over channels → 7x7 conv → gate. The conv
        // starts at zero so that either gate starts as the identity (see `attend`).
        let attention = cfg.attention.then(|| {
            Conv::with_init(
                &root.sub("attention").sub("conv"),
                [2, 1, 7, 1, 3, 1],
                true,
                ConvInit::Zero,
            )
        });
        let h = root.sub("head");
        let head1 = Conv::new(&h.sub("conv1"), fused, cfg.head_channels, 1, 1, 0, 1, true);
        let head2 = Conv::new(
            &h.sub("conv2"),
            cfg.head_channels,
            cfg.head_out_channels(),
            1,
            1,
            0,
            1,
            true,
        );
        Ok(DepthNet {
            cfg: cfg.clone(),
            rgb,
            decoder,
            radar,
            radar_skip,
            attention,
            head1,
            head2,
        })
    }

    /// The configuration the network was built from.
    pub fn config(&self) -> &ModelConfig {
        &self.cfg
    }

    /// Raw head output at low resolution: image `[B,3,H,W]` (ImageNet-normalised), radar
    /// `[B,C,H,W]` in metres (0 = none; ignored when fusion = none) → `[B,2K,h,w]` ordinal
    /// logits (channel 2k = a_k, 2k+1 = b_k) or `[B,1,h,w]` depth in metres.
    /// h×w is stride 8 (top-down decoder) or 32 (released decoder).
    pub fn forward_logits_t(&self, image: &Tensor, radar: &Tensor, train: bool) -> Tensor {
        self.forward_logits_tap(image, radar, train, &mut |_, _| {})
    }

    /// [`DepthNet::forward_logits_t`] that shows `tap` the intermediate features, in graph
    /// (for Grad-CAM++, `depthsense explain`): `rgb.layer1` … `rgb.layer4` (C1..C4),
    /// `decoder` (image features at head resolution) and, for late fusion, `radar` (the radar
    /// branch output before it is resized to the decoder's resolution).
    pub fn forward_logits_tap(
        &self,
        image: &Tensor,
        radar: &Tensor,
        train: bool,
        tap: &mut dyn FnMut(&str, &Tensor),
    ) -> Tensor {
        let cfg = &self.cfg;
        let (image, radar) = &self.downscale_inputs(image, radar);
        // The network sees radar depth scaled by 1/β (the caller passes metres), or in metres
        // as the authors' code feeds it (`radar_in_metres`, released).
        let radar_scale = if cfg.radar_in_metres {
            1.0
        } else {
            1.0 / cfg.sid.beta_m
        };
        let radar_scaled = || radar.to_kind(image.kind()) * radar_scale;
        let input = match cfg.fusion {
            Fusion::Early => Tensor::cat(&[image.shallow_clone(), radar_scaled()], 1),
            _ => image.shallow_clone(),
        };
        let c = self.rgb.forward_t(&input, train);
        for (i, t) in c.iter().enumerate() {
            tap(&format!("rgb.layer{}", i + 1), t);
        }
        let mut f = self.decoder.forward(&c);
        tap("decoder", &f);
        if let Some(rb) = &self.radar {
            let rf = rb.forward_t(&radar_scaled(), train);
            tap("radar", &rf);
            let r = resize_to(&rf, hw_of(&f), false);
            f = Tensor::cat(&[f, r], 1);
        }
        if let Some(skip) = &self.radar_skip {
            let s = skip.forward(&radar_scaled(), hw_of(&f));
            tap("radar_skip", &s);
            f = Tensor::cat(&[f, s], 1);
        }
        f = self.attend(&f);
        if cfg.head_pre_dropout {
            f = crate::sync_bn::feature_dropout(&f, cfg.dropout, train);
        }
        let y = crate::sync_bn::feature_dropout(&self.head1.forward(&f).relu(), cfg.dropout, train);
        let y = self.head2.forward(&y);
        match cfg.head {
            HeadKind::Ordinal => y,
            // Regression heads: depth in metres, bounded to (0, β).
            HeadKind::L1 | HeadKind::L2 => y.sigmoid() * cfg.sid.beta_m,
        }
    }

    /// `input_downscale` = s > 1: image `[B,3,H,W]` → `[B,3,H/s,W/s]` by s×s averaging; radar
    /// `[B,C,H,W]` → `[B,C,H/r,W/r]` keeping the nearest non-zero depth of each r×r cell (SPEC
    /// §5: nearest wins), r = `radar_downscale` (default s). Outputs are still decoded at
    /// `out_height`×`out_width`.
    fn downscale_inputs(&self, image: &Tensor, radar: &Tensor) -> (Tensor, Tensor) {
        let s = self.cfg.input_downscale;
        let r = self.cfg.radar_downscale.unwrap_or(s);
        let image_s = if s > 1 {
            image.avg_pool2d([s, s], [s, s], [0, 0], false, true, None::<i64>)
        } else {
            image.shallow_clone()
        };
        (image_s, nearest_depth_pool(radar, r))
    }

    /// The spatial attention module (SPEC §6, CBAM): `[B,C,h,w]` → `[B,C,h,w]`, the features
    /// times a per-pixel gate from [mean, max] over channels → 7x7 conv. Identity without it.
    ///
    /// The gate is [`ModelConfig::attention_gate`]: ½ + σ(s) in the presets (cannot switch the
    /// features off), or 2σ(s) (the paper's σ(s) times 2, which the linear 1x1 head absorbs).
    /// With the conv starting at zero both start as the identity instead of halving (σ(0) = ½)
    /// or, with a random conv, saturating the features.
    pub(crate) fn attend(&self, f: &Tensor) -> Tensor {
        match &self.attention {
            Some(att) => {
                let mean = f.mean_dim(1, true, f.kind());
                let (max, _) = f.max_dim(1, true);
                let s = att.forward(&Tensor::cat(&[mean, max], 1));
                match self.cfg.attention_gate {
                    AttentionGate::Double => f * (s.sigmoid() * 2.0),
                    AttentionGate::Bounded => f * (s.sigmoid() + 0.5),
                }
            }
            None => f.shallow_clone(),
        }
    }

    /// Head output at low resolution (see [`DepthNet::forward_logits_t`] for inputs):
    /// ordinal → `[B,K,h,w]` logit differences z_k = b_k − a_k (SPEC §7); regression →
    /// `[B,1,h,w]` depth in metres.
    ///
    /// With `clamp_logits` (released conventions) the ordinal output is instead
    /// `[B,K,out_height,out_width]`: the 2K logits are upsampled to the output resolution,
    /// clamped to [1e-8, 1e8] and then paired ([`ordinal::clamped_pair_differences`]), because
    /// the clamp does not commute with upsampling. `loss`, `decode` and
    /// [`ordinal::ordinal_levels`] take either form.
    pub fn forward_t(&self, image: &Tensor, radar: &Tensor, train: bool) -> Tensor {
        let y = self.forward_logits_t(image, radar, train);
        let cfg = &self.cfg;
        match cfg.head {
            HeadKind::Ordinal if cfg.clamp_logits => ordinal::clamped_pair_differences(
                &y,
                cfg.out_height,
                cfg.out_width,
                cfg.align_corners,
            ),
            HeadKind::Ordinal => ordinal::pair_differences(&y),
            HeadKind::L1 | HeadKind::L2 => y,
        }
    }

    /// Scalar training loss of a [`DepthNet::forward_t`] output against `target_m`
    /// `[B,1,H,W]` (metres, 0 = invalid), upsampling to the target's size internally.
    pub fn loss(&self, out: &Tensor, target_m: &Tensor) -> Tensor {
        let ac = self.cfg.align_corners;
        match self.cfg.head {
            HeadKind::Ordinal => ordinal::ordinal_loss(out, target_m, &self.cfg.sid, ac),
            HeadKind::L1 => ordinal::regression_loss(out, target_m, RegressionLoss::L1, ac),
            HeadKind::L2 => {
                let kind = RegressionLoss::L2 {
                    scale_m: self.cfg.sid.beta_m,
                };
                ordinal::regression_loss(out, target_m, kind, ac)
            }
        }
    }

    /// [`DepthNet::loss`] with the target's valid pixels gathered beforehand (`sparse`, of
    /// `target_m`): the ordinal loss then needs no device→host synchronisation; the regression
    /// heads use the dense `target_m` as before.
    pub fn loss_sparse(
        &self,
        out: &Tensor,
        target_m: &Tensor,
        sparse: &ordinal::SparseTarget,
    ) -> Tensor {
        match self.cfg.head {
            HeadKind::Ordinal => {
                ordinal::ordinal_loss_at(out, sparse, &self.cfg.sid, self.cfg.align_corners)
            }
            HeadKind::L1 | HeadKind::L2 => self.loss(out, target_m),
        }
    }

    /// Depth `[B,1,out_height,out_width]` in metres from a [`DepthNet::forward_t`] output.
    pub fn decode(&self, out: &Tensor) -> Tensor {
        self.decode_to(out, self.cfg.out_height, self.cfg.out_width)
    }

    /// Depth `[B,1,height,width]` in metres from a [`DepthNet::forward_t`] output.
    pub fn decode_to(&self, out: &Tensor, height: i64, width: i64) -> Tensor {
        let ac = self.cfg.align_corners;
        match self.cfg.head {
            HeadKind::Ordinal => ordinal::ordinal_decode(out, &self.cfg.sid, height, width, ac),
            HeadKind::L1 | HeadKind::L2 => (ordinal::upsample(out, height, width, ac)
                .to_kind(Kind::Float)
                - self.cfg.sid.decode_offset_m)
                .clamp_min(0.0),
        }
    }

    /// Resolution of the head output for an input of `height`×`width`.
    pub fn head_resolution(&self, height: i64, width: i64) -> (i64, i64) {
        let mut rows = MacRows::new();
        let sizes = self.rgb.count((height, width), &mut rows);
        self.decoder.count(&sizes, &mut rows)
    }

    /// Multiply-adds per conv layer for one image of `height`×`width` (analytic, SPEC §6
    /// shapes), in network order; bilinear upsampling, pooling and the loss are not counted.
    pub fn mac_rows(&self, height: i64, width: i64) -> MacRows {
        let mut rows = MacRows::new();
        let sizes = self.rgb.count((height, width), &mut rows); // C1..C4
        let hw = self.decoder.count(&sizes, &mut rows);
        if let Some(r) = &self.radar {
            r.count((height, width), &mut rows);
        }
        if let Some(s) = &self.radar_skip {
            s.count(hw, &mut rows);
        }
        if let Some(a) = &self.attention {
            a.count(hw, &mut rows);
        }
        let o = self.head1.count(hw, &mut rows);
        self.head2.count(o, &mut rows);
        rows
    }
}

#[cfg(test)]
mod downscale_tests {
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

    /// `tiny` seeing its 64x128 input at 1/2.
    fn tiny_half_64x128() -> ModelConfig {
        let mut cfg = ModelConfig::tiny();
        cfg.input_downscale = 2;
        cfg.out_height = 64;
        cfg.out_width = 128;
        cfg
    }

    #[test]
    fn radar_downscale_sets_the_radar_branch_resolution_only() {
        let mut cfg = tiny_half_64x128();
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let img = Tensor::zeros([1, 3, 64, 128], (Kind::Float, tch::Device::Cpu));
        let radar = Tensor::ones([1, 1, 64, 128], (Kind::Float, tch::Device::Cpu)) * 10.0;
        let same = DepthNet::new(&vs.root(), &cfg).unwrap();
        let (i, r) = same.downscale_inputs(&img, &radar);
        assert_eq!(
            (i.size(), r.size()),
            (vec![1, 3, 32, 64], vec![1, 1, 32, 64])
        );
        cfg.radar_downscale = Some(1);
        let vs1 = nn::VarStore::new(tch::Device::Cpu);
        let full = DepthNet::new(&vs1.root(), &cfg).unwrap();
        let (i, r) = full.downscale_inputs(&img, &radar);
        assert_eq!(
            (i.size(), r.size()),
            (vec![1, 3, 32, 64], vec![1, 1, 64, 128])
        );
        // the head resolution does not change: the radar features are resized to it
        let a = same.forward_t(&img, &radar, false).size();
        let b = full.forward_t(&img, &radar, false).size();
        assert_eq!(a, b);
        // early fusion concatenates radar and image: the factors must agree
        cfg.fusion = Fusion::Early;
        assert!(cfg.validate().is_err());
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

    #[test]
    fn radar_skip_adds_a_path_at_head_resolution_that_sees_one_return() {
        let mut cfg = tiny_half_64x128();
        cfg.radar_skip_channels = 8;
        cfg.attention = false;
        tch::manual_seed(3);
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let net = DepthNet::new(&vs.root(), &cfg).unwrap();
        let names: Vec<String> = vs.variables().into_keys().collect();
        assert!(
            names.iter().any(|n| n == "radar_skip.conv2.weight"),
            "{names:?}"
        );
        // silence the stride-32 radar branch so that only the skip path sees the radar
        tch::no_grad(|| {
            for (n, mut t) in vs.variables() {
                if n.starts_with("radar.") {
                    let _ = t.zero_();
                }
            }
        });
        let img = Tensor::zeros([1, 3, 64, 128], (Kind::Float, tch::Device::Cpu));
        let none = Tensor::zeros([1, 1, 64, 128], (Kind::Float, tch::Device::Cpu));
        let one = none.copy();
        let _ = one.narrow(2, 40, 1).narrow(3, 100, 1).fill_(12.0);
        let a = net.forward_logits_t(&img, &none, false);
        let b = net.forward_logits_t(&img, &one, false);
        let diff = (a - b).abs().sum_dim_intlist(1, false, Kind::Float);
        let (_, h, w) = diff.size3().unwrap();
        let flat: Vec<f32> = Vec::try_from(diff.reshape([-1])).unwrap();
        // return at (40, 100) → (20, 50) at the input's 1/2 → head cell (2, 6) at stride 8
        // (cells of 8×8); two 3x3 convs and a 1x1 head reach ±2 cells, no further.
        let (mut near, mut far) = (0.0f32, 0.0f32);
        for y in 0..h {
            for x in 0..w {
                let v = flat[(y * w + x) as usize];
                if (y - 2).abs() <= 2 && (x - 6).abs() <= 2 {
                    near += v;
                } else {
                    far += v;
                }
            }
        }
        assert!(near > 0.0 && far == 0.0, "near {near} far {far}");
        let skip_macs: u64 = net
            .mac_rows(64, 128)
            .iter()
            .filter(|r| r.0.starts_with("radar_skip"))
            .map(|r| r.1)
            .sum();
        // mac_rows takes the encoder's input size: 64×128 → head 8×16; two 3x3 convs there
        assert_eq!(skip_macs, (8 * 9 + 8 * 8 * 9) * 8 * 16);
        // without the field the config serialises as before (old checkpoints read back)
        cfg.radar_skip_channels = 0;
        let js = serde_json::to_string(&cfg).unwrap();
        assert!(!js.contains("radar_skip"));
    }
}
