//! The DepthSense network (SPEC §6) assembled from its boxes: the RGB encoder
//! ([`crate::encoder`]), the image decoder ([`crate::decoder`]), the radar branch
//! ([`crate::radar_branch`]), fusion and spatial attention ([`crate::fusion`]) and the head
//! ([`crate::head`]); then the loss and the decoding to metres ([`crate::ordinal`]).

use crate::sync_bn::TrainHooks;
use tch::{nn, Kind, Tensor};

use crate::decoder::Decoder;
use crate::encoder::{ResNet, ResNetSpec};
use crate::fusion::{self, LateFusion, SpatialAttention};
use crate::head::Head;
use crate::layers::{hw_of, MacRows, P};
use crate::ordinal::{self, RegressionLoss};
use crate::precision::InferenceLayout;
use crate::radar_branch::nearest_depth_pool;
use crate::ModelError;
use depthsense_config::{HeadKind, ModelConfig};

/// The DepthSense network. Build with [`DepthNet::new`]; variables live in the caller's
/// VarStore under `rgb.`, `decoder.`, `radar.`, `radar_skip.`, `attention.`, `head.`.
pub struct DepthNet {
    cfg: ModelConfig,
    rgb: ResNet,
    decoder: Decoder,
    /// The radar branch and radar path of late fusion (`radar.`, `radar_skip.`).
    late: Option<LateFusion>,
    attention: Option<SpatialAttention>,
    head: Head,
    /// The inference graph ([`DepthNet::prepare_inference`]): BatchNorm folded into the convs
    /// (evaluation mode only) and the fused ordinal decode.
    inference: std::cell::Cell<bool>,
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
        Self::with_hooks(p, cfg, &TrainHooks::default())
    }

    /// [`DepthNet::new`] for data-parallel training: the BatchNorm layers and the head's
    /// dropout are built with `hooks` (`crate::sync_bn`).
    pub fn with_hooks(
        p: &nn::Path,
        cfg: &ModelConfig,
        hooks: &TrainHooks,
    ) -> Result<DepthNet, ModelError> {
        cfg.validate()?;
        let root = P::root(p);
        let in_ch = fusion::encoder_in_channels(cfg);
        let spec = ResNetSpec::standard(cfg.backbone_depth, in_ch, cfg.backbone_width, cfg.stem);
        let rgb = ResNet::new(&root.sub("rgb"), &spec, hooks.batch_norm.as_ref());
        let ch = rgb.channels;
        let decoder = Decoder::new(
            &root,
            cfg.decoder,
            [ch[1], ch[2], ch[3]],
            cfg.decoder_channels,
        );
        let late = LateFusion::new(&root, cfg, hooks);
        let fused = decoder.out_channels() + late.as_ref().map_or(0, LateFusion::out_channels);
        let attention = cfg
            .attention
            .then(|| SpatialAttention::new(&root, cfg.attention_gate));
        let head = Head::new(&root, fused, cfg, hooks);
        Ok(DepthNet {
            cfg: cfg.clone(),
            rgb,
            decoder,
            late,
            attention,
            head,
            inference: std::cell::Cell::new(false),
        })
    }

    /// Makes this network the inference graph, once its weights are loaded (`predict`, `eval`,
    /// `explain`, the experiments' test runs): every BatchNorm folded into the conv before it
    /// (W' = W·γ/√(σ²+ε), b' = β − μ·γ/√(σ²+ε); used in evaluation mode only, the training
    /// graph is untouched) and, on the CPU, the ordinal decode without the full-resolution
    /// `[B,K,H,W]` tensor ([`crate::fused_decode`]). Its decoded bins equal the training
    /// graph's on ≥ 99.99 % of pixels (float rounding). The folded weights are stored in
    /// `layout` ([`InferenceLayout::Fastest`]: channels-last on the CPU; the decoder and head
    /// convs then follow their inputs' layout). Weights written after this (a load: libtorch
    /// counts every in-place write) are folded again at the next forward.
    pub fn prepare_inference(&self, layout: InferenceLayout) {
        self.rgb.fold_batch_norm(layout);
        if let Some(late) = &self.late {
            late.fold_batch_norm(layout);
        }
        self.inference.set(true);
    }

    /// Whether [`DepthNet::prepare_inference`] has run.
    pub fn is_inference_graph(&self) -> bool {
        self.inference.get()
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
        let radar_scale = fusion::radar_scale(cfg);
        let radar_scaled = || radar.to_kind(image.kind()) * radar_scale;
        let input = fusion::encoder_input(cfg, image, &radar_scaled);
        let c = self.rgb.forward_t(&input, train);
        for (i, t) in c.iter().enumerate() {
            tap(&format!("rgb.layer{}", i + 1), t);
        }
        let mut f = self.decoder.forward(&c);
        tap("decoder", &f);
        if let Some(late) = &self.late {
            f = late.forward_t(f, &radar_scaled, train, tap);
        }
        f = self.attend(&f);
        self.head.forward_t(f, cfg, train)
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

    /// The spatial attention module ([`SpatialAttention`]): `[B,C,h,w]` → `[B,C,h,w]`.
    /// Identity without it.
    pub(crate) fn attend(&self, f: &Tensor) -> Tensor {
        match &self.attention {
            Some(att) => att.forward(f),
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
            // The released head's differences are already at full resolution: nothing to fuse.
            HeadKind::Ordinal if self.inference.get() && hw_of(out) != (height, width) => {
                crate::sid::levels_to_depth(
                    &self.cfg.sid,
                    &crate::fused_decode::ordinal_levels_fused(out, height, width, ac),
                )
            }
            HeadKind::Ordinal => ordinal::ordinal_decode(out, &self.cfg.sid, height, width, ac),
            HeadKind::L1 | HeadKind::L2 => (ordinal::upsample(out, height, width, ac)
                .to_kind(Kind::Float)
                - self.cfg.sid.decode_offset_m)
                .clamp_min(0.0),
        }
    }

    /// [`DepthNet::decode`] at the pixels of `at` only (its grid `(B, out_height, out_width)`):
    /// depth `[N]` in metres, float — the scorer reads nothing else, so validation need not
    /// build the full-resolution `[B,K,H,W]` ordinal tensor. Equal to gathering `decode` at
    /// those pixels up to float rounding of the interpolation ([`ordinal::upsample_at`]).
    pub fn decode_at(&self, out: &Tensor, at: &ordinal::SparseTarget) -> Tensor {
        let ac = self.cfg.align_corners;
        match self.cfg.head {
            HeadKind::Ordinal => ordinal::ordinal_decode_at(out, at, &self.cfg.sid, ac),
            HeadKind::L1 | HeadKind::L2 => (ordinal::upsample_at(out, at, ac)
                .squeeze_dim(1)
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
        if let Some(late) = &self.late {
            late.count((height, width), hw, &mut rows);
        }
        if let Some(a) = &self.attention {
            a.count(hw, &mut rows);
        }
        self.head.count(hw, &mut rows);
        rows
    }
}

#[cfg(test)]
mod downscale_tests {
    use super::*;
    use depthsense_config::Fusion;

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
