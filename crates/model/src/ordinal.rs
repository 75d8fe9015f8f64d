//! Ordinal regression in the exact and efficient form (SPEC §7), and the L1/L2 heads.
//!
//! The head produces 2K channels at low resolution (channel 2k = a_k, 2k+1 = b_k, SPEC §6.1).
//! Because bilinear upsampling is linear, z_k = b_k − a_k can be formed at low resolution and
//! upsampled alone (K instead of 2K channels); P_k = σ(z_k), so the DORN loss is binary
//! cross-entropy with logits on z, and P_k ≥ 0.5 ⇔ z_k ≥ 0.

use tch::{Kind, Tensor};

use crate::{sid, SidConfig};

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
    let (b, k, h, w) = z.size4().expect("ordinal_loss: z must be [B,K,h,w]");
    let (tb, _, th, tw) = target_m
        .size4()
        .expect("ordinal_loss: target must be [B,1,H,W]");
    assert_eq!(b, tb, "ordinal_loss: batch of z and target differ");
    let z = if z.kind() == Kind::Double {
        z.shallow_clone()
    } else {
        z.to_kind(Kind::Float)
    };
    let flat_t = target_m.reshape([-1]);
    let idx = flat_t.gt(0.0).nonzero().squeeze_dim(1); // [N] flat indices into B·H·W
    let n = idx.size()[0];
    if n == 0 {
        return z.sum(z.kind()) * 0.0;
    }
    let depth = flat_t.index_select(0, &idx);
    let bi = idx.divide_scalar_mode(th * tw, "floor");
    let rem = idx.remainder(th * tw);
    let yi = rem.divide_scalar_mode(tw, "floor");
    let xi = rem.remainder(tw);
    let (y0, y1, wy) = taps(&yi, th, h, align_corners);
    let (x0, x1, wx) = taps(&xi, tw, w, align_corners);
    let rows = z.permute([0, 2, 3, 1]).reshape([b * h * w, k]); // [B·h·w, K]
    let base = &bi * (h * w);
    let tap = |yy: &Tensor, xx: &Tensor| rows.index_select(0, &(&base + yy * w + xx));
    let (wy, wx) = (
        wy.to_kind(z.kind()).unsqueeze(1),
        wx.to_kind(z.kind()).unsqueeze(1),
    );
    let (vy, vx): (Tensor, Tensor) = (1.0 - &wy, 1.0 - &wx);
    let top: Tensor = tap(&y0, &x0) * &vx + tap(&y0, &x1) * &wx;
    let bottom: Tensor = tap(&y1, &x0) * &vx + tap(&y1, &x1) * &wx;
    let zp: Tensor = top * vy + bottom * wy; // [N,K]
    let label = sid::labels(sid_cfg, &depth).unsqueeze(1); // [N,1]
    let ks = Tensor::arange(k, (Kind::Int64, z.device())).unsqueeze(0);
    let y = ks.lt_tensor(&label).to_kind(z.kind()); // [N,K]
    (zp.softplus() - y * &zp).sum(z.kind()) / n as f64
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

/// L1 (`squared = false`) or L2 regression loss over valid pixels; `pred_m` `[B,1,h,w]` is
/// upsampled to the target's size.
pub fn regression_loss(
    pred_m: &Tensor,
    target_m: &Tensor,
    squared: bool,
    align_corners: bool,
) -> Tensor {
    let (_, _, th, tw) = target_m
        .size4()
        .expect("regression_loss: target must be [B,1,H,W]");
    let pred = upsample(pred_m, th, tw, align_corners).to_kind(Kind::Float);
    let valid = target_m.gt(0.0).to_kind(Kind::Float);
    let diff = (pred - target_m.to_kind(Kind::Float)) * &valid;
    let err = if squared { diff.square() } else { diff.abs() };
    err.sum(Kind::Float) / valid.sum(Kind::Float).clamp_min(1.0)
}
