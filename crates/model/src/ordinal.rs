//! Ordinal regression in the exact and efficient form (SPEC §7), and the L1/L2 heads.
//!
//! The head produces 2K channels at low resolution (channel 2k = a_k, 2k+1 = b_k, SPEC §6.1).
//! Because bilinear upsampling is linear, z_k = b_k − a_k can be formed at low resolution and
//! upsampled alone (K instead of 2K channels); P_k = σ(z_k), so the DORN loss is binary
//! cross-entropy with logits on z, and P_k ≥ 0.5 ⇔ z_k ≥ 0.

use tch::{Device, Kind, Tensor};

use crate::sid;
use depthsense_config::SidConfig;

/// Pairwise logit differences: `[B,2K,h,w]` → `[B,K,h,w]`, z_k = b_k − a_k.
pub fn pair_differences(logits: &Tensor) -> Tensor {
    let (b, c, h, w) = logits
        .size4()
        .expect("pair_differences: expected a [B,2K,h,w] tensor");
    assert!(c % 2 == 0, "pair_differences: odd channel count {c}");
    let pairs = logits.view([b, c / 2, 2, h, w]);
    pairs.select(2, 1) - pairs.select(2, 0)
}

/// Lower and upper bound of the authors' logit clamp (SPEC §7, `clamp_logits`).
pub const CLAMP_MIN: f64 = 1e-8;
/// Upper bound of the authors' logit clamp.
pub const CLAMP_MAX: f64 = 1e8;

/// The authors' released head (SPEC §6.1, §7; `clamp_logits`): the 2K logits `[B,2K,h,w]` are
/// bilinearly upsampled to `height`×`width` **first**, clamped to [1e-8, 1e8], and only then
/// paired: → `[B,K,height,width]`, z_k = clamp(b_k) − clamp(a_k).
///
/// The clamp is not linear, so unlike [`pair_differences`] this cannot be formed at low
/// resolution; it costs the full-resolution 2K-channel tensor the released code builds.
/// Their P_k = softmax(clamp(a_k), clamp(b_k))[1] = σ(z_k), so P_k ≥ 0.5 ⇔ z_k ≥ 0 (a pixel
/// whose a_k and b_k are both clamped to 1e-8 gives z_k = 0, P_k = 0.5, and counts), and the
/// usual loss, levels and decode apply to z unchanged (their upsampling is the identity).
pub fn clamped_pair_differences(
    logits: &Tensor,
    height: i64,
    width: i64,
    align_corners: bool,
) -> Tensor {
    let up = upsample(logits, height, width, align_corners).clamp(CLAMP_MIN, CLAMP_MAX);
    pair_differences(&up)
}

/// Bilinear upsampling of `[B,C,h,w]` to `[B,C,H,W]` (identity when the size already matches).
pub fn upsample(x: &Tensor, height: i64, width: i64, align_corners: bool) -> Tensor {
    let (_, _, h, w) = x.size4().expect("upsample: expected a 4-d tensor");
    if h == height && w == width {
        return x.shallow_clone();
    }
    x.upsample_bilinear2d([height, width], align_corners, None, None)
}

/// Ordinal loss (SPEC §7) from low-resolution differences `z` `[B,K,h,w]` and the target
/// `[B,1,H,W]` in metres (0 = invalid): z is bilinearly interpolated to H×W **at the valid
/// pixels only** (the same four taps and weights as `upsample_bilinear2d`, so the result equals
/// upsampling everything and masking), y_k = [k < l],
/// Σ_k BCE-with-logits(z_k, y_k) = Σ_k softplus(z_k) − y_k·z_k, mean over valid pixels.
/// Lidar targets are sparse (a few % of pixels), so this needs a fraction of the memory and
/// time of the dense form ([`ordinal_loss_dense`]). Returns a scalar (0 when no pixel is valid).
pub fn ordinal_loss(
    z: &Tensor,
    target_m: &Tensor,
    sid_cfg: &SidConfig,
    align_corners: bool,
) -> Tensor {
    ordinal_loss_at(
        z,
        &SparseTarget::from_dense(target_m),
        sid_cfg,
        align_corners,
    )
}

/// The valid pixels of a `[B,1,H,W]` target: flat indices into B·H·W (ascending, int64) and
/// their depths in metres, with their count known on the host — so a loss over them needs no
/// device→host synchronisation ([`SparseTarget::from_host`] gathers them before the upload;
/// [`SparseTarget::from_dense`] on the device, one `nonzero` sync).
#[derive(Debug)]
pub struct SparseTarget {
    /// `[N]` int64 flat indices into B·H·W, ascending.
    pub index: Tensor,
    /// `[N]` depths in metres (> 0), the target's kind.
    pub depth_m: Tensor,
    /// N (host).
    pub count: i64,
    /// (B, H, W) of the dense target.
    pub shape: (i64, i64, i64),
}

impl SparseTarget {
    /// From a row-major `[B,1,H,W]` host target (0 = invalid; `shape` = (B, H, W)), gathered on
    /// the host and uploaded to `device` (non-blocking from pinned memory on CUDA).
    pub fn from_host(target_m: &[f32], shape: (i64, i64, i64), device: Device) -> Self {
        let (index, depth): (Vec<i64>, Vec<f32>) = target_m
            .iter()
            .enumerate()
            .filter(|(_, &d)| d > 0.0)
            .map(|(i, &d)| (i as i64, d))
            .unzip();
        Self {
            count: index.len() as i64,
            index: to_device_async(Tensor::from_slice(&index), device),
            depth_m: to_device_async(Tensor::from_slice(&depth), device),
            shape,
        }
    }

    /// From a `[B,1,H,W]` target tensor (`nonzero`: one device→host synchronisation on CUDA).
    pub fn from_dense(target_m: &Tensor) -> Self {
        let (b, _, h, w) = target_m
            .size4()
            .expect("ordinal_loss: target must be [B,1,H,W]");
        let flat = target_m.reshape([-1]);
        let index = flat.gt(0.0).nonzero().squeeze_dim(1);
        let count = index.size()[0];
        Self {
            depth_m: flat.index_select(0, &index),
            index,
            count,
            shape: (b, h, w),
        }
    }
}

/// `t` on `device`: a plain copy to the CPU, else through pinned memory without blocking the
/// host (the copy is ordered on the current stream before any kernel that reads it); a blocking
/// copy if no pinned memory can be had.
pub fn to_device_async(t: Tensor, device: Device) -> Tensor {
    if device == Device::Cpu || t.device() == device {
        return t.to_device(device);
    }
    depthsense_torch_ext::to_device_nonblocking(&t, device)
}

/// [`ordinal_loss`] over the valid pixels `target` (no `nonzero`, no host synchronisation).
pub fn ordinal_loss_at(
    z: &Tensor,
    target: &SparseTarget,
    sid_cfg: &SidConfig,
    align_corners: bool,
) -> Tensor {
    let (b, k, _, _) = z.size4().expect("ordinal_loss: z must be [B,K,h,w]");
    assert_eq!(
        b, target.shape.0,
        "ordinal_loss: batch of z and target differ"
    );
    let z = if z.kind() == Kind::Double {
        z.shallow_clone()
    } else {
        z.to_kind(Kind::Float)
    };
    let n = target.count;
    if n == 0 {
        return z.sum(z.kind()) * 0.0;
    }
    let zp = upsample_at(&z, target, align_corners); // [N,K]
    let label = sid::labels(sid_cfg, &target.depth_m).unsqueeze(1); // [N,1]
    let ks = Tensor::arange(k, (Kind::Int64, z.device())).unsqueeze(0);
    let y = ks.lt_tensor(&label).to_kind(z.kind()); // [N,K]
    (zp.softplus() - y * &zp).sum(z.kind()) / n as f64
}

/// Bilinear upsampling of `x` `[B,C,h,w]` to the `(B, H, W)` grid of `at`, evaluated at its
/// pixels only: `[N,C]` (x's kind), row n = `upsample(x)[b_n, :, y_n, x_n]` with the four taps
/// and weights `upsample_bilinear2d` uses (equal to it up to float rounding; the identity when
/// h×w = H×W). A fraction of the dense upsampling's time and memory when the pixels are few.
pub fn upsample_at(x: &Tensor, at: &SparseTarget, align_corners: bool) -> Tensor {
    let (b, c, h, w) = x.size4().expect("upsample_at: x must be [B,C,h,w]");
    let (tb, th, tw) = at.shape;
    assert_eq!(b, tb, "upsample_at: batch of x and the pixels differ");
    let idx = &at.index;
    let bi = idx.divide_scalar_mode(th * tw, "floor");
    let rem = idx.remainder(th * tw);
    let yi = rem.divide_scalar_mode(tw, "floor");
    let xi = rem.remainder(tw);
    let (y0, y1, wy) = taps(&yi, th, h, align_corners);
    let (x0, x1, wx) = taps(&xi, tw, w, align_corners);
    let rows = x.permute([0, 2, 3, 1]).reshape([b * h * w, c]); // [B·h·w, C]
    let base = &bi * (h * w);
    let tap = |yy: &Tensor, xx: &Tensor| rows.index_select(0, &(&base + yy * w + xx));
    let (wy, wx) = (
        wy.to_kind(x.kind()).unsqueeze(1),
        wx.to_kind(x.kind()).unsqueeze(1),
    );
    let (vy, vx): (Tensor, Tensor) = (1.0 - &wy, 1.0 - &wx);
    let top: Tensor = tap(&y0, &x0) * &vx + tap(&y0, &x1) * &wx;
    let bottom: Tensor = tap(&y1, &x0) * &vx + tap(&y1, &x1) * &wx;
    top * vy + bottom * wy
}

/// [`ordinal_decode`] at the pixels of `at` only: depth `[N]` in metres (float), level
/// Σ_k [z_k ≥ 0] of the bilinearly interpolated differences ([`upsample_at`]).
pub fn ordinal_decode_at(
    z: &Tensor,
    at: &SparseTarget,
    sid_cfg: &SidConfig,
    align_corners: bool,
) -> Tensor {
    let levels = upsample_at(z, at, align_corners)
        .ge(0.0)
        .sum_dim_intlist(1, false, Kind::Int64);
    sid::levels_to_depth(sid_cfg, &levels)
}

/// Source taps of bilinear upsampling from `inp` to `out` samples along one axis for the
/// output indices `i`: (i0, i1, λ) with value = (1 − λ)·v[i0] + λ·v[i1], as ATen computes them.
fn taps(i: &Tensor, out: i64, inp: i64, align_corners: bool) -> (Tensor, Tensor, Tensor) {
    let f = i.to_kind(Kind::Double);
    let src = if align_corners {
        if out > 1 {
            f * ((inp - 1) as f64 / (out - 1) as f64)
        } else {
            f * 0.0
        }
    } else {
        ((f + 0.5) * (inp as f64 / out as f64) - 0.5).clamp_min(0.0)
    };
    let i0 = src.floor().clamp(0.0, (inp - 1) as f64);
    let lambda = (&src - &i0).clamp(0.0, 1.0);
    let i0 = i0.to_kind(Kind::Int64);
    let i1 = (&i0 + 1).clamp_max(inp - 1);
    (i0, i1, lambda)
}

/// The dense efficient form: upsample z (K channels) to H×W, BCE with logits everywhere,
/// mean over valid pixels. Equal to [`ordinal_loss`]; kept for tests and comparison.
pub fn ordinal_loss_dense(
    z: &Tensor,
    target_m: &Tensor,
    sid_cfg: &SidConfig,
    align_corners: bool,
) -> Tensor {
    let (_, _, th, tw) = target_m
        .size4()
        .expect("ordinal_loss: target must be [B,1,H,W]");
    let z = upsample(z, th, tw, align_corners);
    let z = if z.kind() == Kind::Double {
        z
    } else {
        z.to_kind(Kind::Float)
    };
    let k = z.size()[1];
    let valid = target_m.gt(0.0).to_kind(z.kind()); // [B,1,H,W]
    let label = sid::labels(sid_cfg, target_m); // [B,1,H,W] int64
    let ks = Tensor::arange(k, (Kind::Int64, z.device())).view([1, k, 1, 1]);
    let y = ks.lt_tensor(&label).to_kind(z.kind()); // [B,K,H,W]
    let per_pixel = (z.softplus() - &y * &z).sum_dim_intlist(1, true, z.kind()); // [B,1,H,W]
    let n = valid.sum(z.kind()).clamp_min(1.0);
    (per_pixel * &valid).sum(z.kind()) / n
}

/// Decoded levels l̂ = Σ_k [z_k ≥ 0] at H×W, `[B,1,H,W]` int64.
pub fn ordinal_levels(z: &Tensor, height: i64, width: i64, align_corners: bool) -> Tensor {
    upsample(z, height, width, align_corners)
        .ge(0.0)
        .sum_dim_intlist(1, true, Kind::Int64)
}

/// Decoded depth `[B,1,H,W]` in metres from low-resolution differences `z` (SPEC §7).
pub fn ordinal_decode(
    z: &Tensor,
    sid_cfg: &SidConfig,
    height: i64,
    width: i64,
    align_corners: bool,
) -> Tensor {
    sid::levels_to_depth(sid_cfg, &ordinal_levels(z, height, width, align_corners))
}

/// The error term of a regression head's loss (SPEC §7 alternatives), per valid pixel with
/// error e = prediction − target in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RegressionLoss {
    /// |e|.
    L1,
    /// e² / (2c): the quadratic part of a Huber loss with threshold c (the depth range β), so
    /// that its gradient e/c never exceeds L1's ±1. Plain e² in metres gives gradients up to
    /// 2β = 160 per pixel; through the head's sigmoid·β output that saturates the sigmoid in
    /// the first steps and the network never moves again (measured: loss ≈ 660 m² flat,
    /// a constant depth map).
    L2 {
        /// The scale c in metres.
        scale_m: f64,
    },
}

/// Regression loss over valid pixels (mean of [`RegressionLoss`]'s term); `pred_m`
/// `[B,1,h,w]` is upsampled to the target's size.
pub fn regression_loss(
    pred_m: &Tensor,
    target_m: &Tensor,
    kind: RegressionLoss,
    align_corners: bool,
) -> Tensor {
    let (_, _, th, tw) = target_m
        .size4()
        .expect("regression_loss: target must be [B,1,H,W]");
    let pred = upsample(pred_m, th, tw, align_corners).to_kind(Kind::Float);
    let valid = target_m.gt(0.0).to_kind(Kind::Float);
    let diff = (pred - target_m.to_kind(Kind::Float)) * &valid;
    let err = match kind {
        RegressionLoss::L1 => diff.abs(),
        RegressionLoss::L2 { scale_m } => diff.square() / (2.0 * scale_m),
    };
    err.sum(Kind::Float) / valid.sum(Kind::Float).clamp_min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A random `[B,1,H,W]` f32 target with `valid` of its pixels > 0 (the rest 0).
    fn target(b: i64, h: i64, w: i64, valid: f64) -> Tensor {
        let opts = (Kind::Float, Device::Cpu);
        let depth = Tensor::rand([b, 1, h, w], opts) * 85.0 + 0.5;
        depth * Tensor::rand([b, 1, h, w], opts).lt(valid)
    }

    #[test]
    fn regression_loss_terms_by_hand() {
        let opts = (Kind::Float, Device::Cpu);
        // prediction 10, 50, 30, 70 m; target 20, 0 (invalid), 30, 30 m
        let pred = Tensor::from_slice(&[10.0f32, 50.0, 30.0, 70.0]).view([1, 1, 2, 2]);
        let target = Tensor::from_slice(&[20.0f32, 0.0, 30.0, 30.0])
            .view([1, 1, 2, 2])
            .to_kind(opts.0);
        let l1 = regression_loss(&pred, &target, RegressionLoss::L1, true).double_value(&[]);
        assert!((l1 - (10.0 + 0.0 + 40.0) / 3.0).abs() < 1e-5, "{l1}");
        let l2 = RegressionLoss::L2 { scale_m: 80.0 };
        let l2 = regression_loss(&pred, &target, l2, true).double_value(&[]);
        assert!(
            (l2 - (100.0 + 0.0 + 1600.0) / 160.0 / 3.0).abs() < 1e-5,
            "{l2}"
        );
    }

    #[test]
    fn ordinal_loss_at_host_indices_equals_nonzero_and_dense_forms() {
        let s = SidConfig::default();
        let gen = tch::Tensor::randn([2, 80, 6, 9], (Kind::Float, Device::Cpu)) * 3.0;
        for (valid, align) in [(0.3, true), (0.05, false), (0.0, false), (1.0, true)] {
            let t = target(2, 23, 41, valid);
            let host: Vec<f32> = Vec::try_from(t.reshape([-1])).unwrap();
            let sparse = SparseTarget::from_host(&host, (2, 23, 41), Device::Cpu);
            assert_eq!(
                sparse.count,
                host.iter().filter(|d| **d > 0.0).count() as i64
            );
            let at = ordinal_loss_at(&gen, &sparse, &s, align).double_value(&[]);
            let nz = ordinal_loss(&gen, &t, &s, align).double_value(&[]);
            let dense = ordinal_loss_dense(&gen, &t, &s, align).double_value(&[]);
            // The same indices, depths and operations as the nonzero path: bit for bit.
            assert_eq!(at.to_bits(), nz.to_bits(), "valid {valid}: {at} vs {nz}");
            assert!(
                (at - dense).abs() <= 1e-6 * dense.abs().max(1.0),
                "{at} vs {dense}"
            );
            if valid == 0.0 {
                assert_eq!(at, 0.0);
            }
        }
    }

    #[test]
    fn decode_at_equals_the_dense_decode_at_those_pixels() {
        let s = SidConfig::default();
        // Drawn from a local generator (crate::test_rng): libtorch's global one is shared with
        // the tests running beside this one, and the bound below is tight (a flip in ~600).
        let mut seed = 0x2545_F491_4F6C_DD1Du64;
        // upsampled 6x9 → 23x41 (both corner conventions), and the identity (23x41)
        for (h, w, align) in [(6, 9, false), (6, 9, true), (23, 41, false)] {
            let z = (crate::test_rng::uniform(&[2, 80, h, w], &mut seed) - 0.5) * 12.0;
            let depth = crate::test_rng::uniform(&[2, 1, 23, 41], &mut seed) * 85.0 + 0.5;
            let t = depth * crate::test_rng::uniform(&[2, 1, 23, 41], &mut seed).lt(0.3);
            let host: Vec<f32> = Vec::try_from(t.reshape([-1])).unwrap();
            let at = SparseTarget::from_host(&host, (2, 23, 41), Device::Cpu);
            let sparse: Vec<f32> = Vec::try_from(ordinal_decode_at(&z, &at, &s, align)).unwrap();
            let dense: Vec<f32> =
                Vec::try_from(ordinal_decode(&z, &s, 23, 41, align).reshape([-1])).unwrap();
            let gathered: Vec<f32> = host
                .iter()
                .zip(&dense)
                .filter(|(d, _)| **d > 0.0)
                .map(|(_, p)| *p)
                .collect();
            assert_eq!(sparse.len(), gathered.len());
            // Interpolation rounding may move a z_k that is ~0 across 0: one bin at most, rarely.
            let differ = sparse.iter().zip(&gathered).filter(|(a, b)| a != b).count();
            assert!(
                differ * 1000 <= sparse.len(),
                "{differ} of {} differ",
                sparse.len()
            );
            if (h, w) == (23, 41) {
                assert_eq!(sparse, gathered, "the identity is exact");
            }
            let zv = upsample_at(&z, &at, align);
            let zd = upsample(&z, 23, 41, align)
                .permute([0, 2, 3, 1])
                .reshape([-1, 80]);
            let zd = zd.index_select(0, &at.index);
            let max = (zv - zd).abs().max().double_value(&[]);
            assert!(max < 1e-5, "interpolated values differ by {max}");
        }
    }

    #[test]
    fn ordinal_loss_at_gradients_equal_the_nonzero_form() {
        let s = SidConfig::default();
        let t = target(2, 17, 30, 0.2);
        let host: Vec<f32> = Vec::try_from(t.reshape([-1])).unwrap();
        let sparse = SparseTarget::from_host(&host, (2, 17, 30), Device::Cpu);
        let z0 = Tensor::randn([2, 80, 5, 8], (Kind::Float, Device::Cpu));
        let a = z0.detach().set_requires_grad(true);
        ordinal_loss_at(&a, &sparse, &s, false).backward();
        let b = z0.detach().set_requires_grad(true);
        ordinal_loss(&b, &t, &s, false).backward();
        assert!(a.grad().equal(&b.grad()));
    }
}
