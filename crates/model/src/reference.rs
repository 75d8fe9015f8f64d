//! The naive DORN ordinal form, kept as a reference for tests (SPEC §7): upsample all 2K
//! channels to full resolution, pairwise softmax, log-probabilities. Slow and memory-hungry;
//! never used for training.

use tch::{Kind, Tensor};

use crate::ordinal::upsample;
use crate::sid;
use depthsense_config::SidConfig;

/// Naive loss from the raw 2K logits `[B,2K,h,w]` and the target `[B,1,H,W]` (0 = invalid):
/// −mean over valid pixels of Σ_k [y_k ln P_k + (1 − y_k) ln(1 − P_k)], P_k = softmax(a_k, b_k)[1].
pub fn naive_loss(
    logits: &Tensor,
    target_m: &Tensor,
    sid_cfg: &SidConfig,
    align_corners: bool,
) -> Tensor {
    let (b, _, th, tw) = target_m.size4().expect("target must be [B,1,H,W]");
    let up = upsample(logits, th, tw, align_corners);
    let k = up.size()[1] / 2;
    let logp = up.view([b, k, 2, th, tw]).log_softmax(2, up.kind());
    let (logp0, logp1) = (logp.select(2, 0), logp.select(2, 1));
    let label = sid::labels(sid_cfg, target_m);
    let ks = Tensor::arange(k, (Kind::Int64, up.device())).view([1, k, 1, 1]);
    let y = ks.lt_tensor(&label).to_kind(up.kind());
    let ones_minus_y: Tensor = 1.0 - &y;
    let ll = (&y * &logp1 + ones_minus_y * &logp0).sum_dim_intlist(1, true, up.kind());
    let valid = target_m.gt(0.0).to_kind(up.kind());
    -(ll * &valid).sum(up.kind()) / valid.sum(up.kind()).clamp_min(1.0)
}

/// Naive decoding: l̂ = Σ_k [P_k ≥ 0.5] with P_k the pairwise softmax at full resolution;
/// returns (levels int64 `[B,1,H,W]`, depth in metres `[B,1,H,W]`).
pub fn naive_decode(
    logits: &Tensor,
    sid_cfg: &SidConfig,
    height: i64,
    width: i64,
    align_corners: bool,
) -> (Tensor, Tensor) {
    let up = upsample(logits, height, width, align_corners);
    let b = up.size()[0];
    let k = up.size()[1] / 2;
    let p1 = up
        .view([b, k, 2, height, width])
        .softmax(2, up.kind())
        .select(2, 1);
    let levels = p1.ge(0.5).sum_dim_intlist(1, true, Kind::Int64);
    let depth = sid::levels_to_depth(sid_cfg, &levels);
    (levels, depth)
}
