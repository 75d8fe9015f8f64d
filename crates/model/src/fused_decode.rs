//! The ordinal decode of the inference graph on the CPU (issue 44), fused: the levels
//! `[B,1,H,W]` of low-resolution differences `z` `[B,K,h,w]` without the full-resolution
//! `[B,K,H,W]` tensor that [`crate::ordinal::ordinal_levels`] upsamples, compares and sums
//! (K·H·W floats: 90 MB per 350x800 image at K = 80, written and read three times).
//!
//! Bilinear interpolation is separable: each low-resolution row is interpolated along the width
//! once (`[K,h,W]`), then every output row blends two of those rows and counts, per pixel, the
//! bins whose value is ≥ 0 — one pass over `K × W` per output row, in cache, on every thread
//! libtorch would use. The taps and weights are PyTorch's `upsample_bilinear2d` (float source
//! index, `align_corners` both ways, borders clamped), so a level differs from the training
//! graph's only where a bin's value is within float rounding of 0 (the equality test: the same
//! level on ≥ 99.99 % of pixels).

use tch::{Device, Kind, Tensor};

/// One output coordinate's two source taps and their weights (PyTorch's
/// `area_pixel_compute_source_index` and `compute_indices_weights_linear`, in f32).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Tap {
    i0: usize,
    i1: usize,
    l0: f32,
    l1: f32,
}

/// The taps of every output coordinate `0..out` from an input axis of `input` samples.
fn taps(input: usize, out: usize, align_corners: bool) -> Vec<Tap> {
    let scale = if align_corners {
        if out > 1 {
            (input as f32 - 1.0) / (out as f32 - 1.0)
        } else {
            0.0
        }
    } else {
        input as f32 / out as f32
    };
    (0..out)
        .map(|d| {
            let src = if align_corners {
                scale * d as f32
            } else {
                (scale * (d as f32 + 0.5) - 0.5).max(0.0)
            };
            let i0 = (src as usize).min(input - 1);
            let i1 = if i0 < input - 1 { i0 + 1 } else { i0 };
            let l1 = src - i0 as f32;
            Tap {
                i0,
                i1,
                l0: 1.0 - l1,
                l1,
            }
        })
        .collect()
}

/// Levels `[B,1,height,width]` (int64) of `z` `[B,K,h,w]`: the number of bins whose
/// bilinearly upsampled value is ≥ 0, as [`crate::ordinal::ordinal_levels`] computes them.
/// A tensor that is not on the CPU takes that unfused path.
pub fn ordinal_levels_fused(z: &Tensor, height: i64, width: i64, align_corners: bool) -> Tensor {
    if z.device() != Device::Cpu {
        return crate::ordinal::ordinal_levels(z, height, width, align_corners);
    }
    let (b, k, h, w) = z.size4().expect("ordinal_levels_fused: [B,K,h,w]");
    let [b, k, h, w, hh, ww] = [b, k, h, w, height, width].map(|v| v as usize);
    let z = Vec::<f32>::try_from(z.to_kind(Kind::Float).contiguous().view([-1]))
        .expect("a float tensor on the CPU");
    let (ty, tx) = (taps(h, hh, align_corners), taps(w, ww, align_corners));
    let mut levels = vec![0i64; b * hh * ww];
    let threads = usize::try_from(tch::get_num_threads()).unwrap_or(1).max(1);
    for (bi, out) in levels.chunks_mut(hh * ww).enumerate() {
        let zb = &z[bi * k * h * w..(bi + 1) * k * h * w];
        let along_w = interpolate_width(zb, k * h, w, &tx);
        let rows_per = hh.div_ceil(threads).max(1);
        std::thread::scope(|s| {
            for (ci, chunk) in out.chunks_mut(rows_per * ww).enumerate() {
                let (along_w, ty) = (&along_w, &ty);
                s.spawn(move || {
                    for (r, row) in chunk.chunks_mut(ww).enumerate() {
                        count_row(along_w, k, h, ww, ty[ci * rows_per + r], row);
                    }
                });
            }
        });
    }
    Tensor::from_slice(&levels).view([b as i64, 1, height, width])
}

/// Every one of `rows` input rows of `w` samples interpolated to `tx.len()` samples.
fn interpolate_width(z: &[f32], rows: usize, w: usize, tx: &[Tap]) -> Vec<f32> {
    let ww = tx.len();
    let mut out = vec![0f32; rows * ww];
    for (src, dst) in z.chunks(w).zip(out.chunks_mut(ww)) {
        for (d, t) in dst.iter_mut().zip(tx) {
            *d = t.l0 * src[t.i0] + t.l1 * src[t.i1];
        }
    }
    out
}

/// One output row's levels: per pixel, the bins k whose blend of the width-interpolated rows
/// `t.i0` and `t.i1` is ≥ 0.
fn count_row(along_w: &[f32], k: usize, h: usize, ww: usize, t: Tap, levels: &mut [i64]) {
    let mut count = vec![0u32; ww];
    for bin in 0..k {
        let r0 = &along_w[(bin * h + t.i0) * ww..][..ww];
        let r1 = &along_w[(bin * h + t.i1) * ww..][..ww];
        for ((c, a), b) in count.iter_mut().zip(r0).zip(r1) {
            *c += u32::from(t.l0 * a + t.l1 * b >= 0.0);
        }
    }
    for (l, c) in levels.iter_mut().zip(count) {
        *l = i64::from(c);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fraction of pixels whose fused level equals the unfused one.
    fn agreement(z: &Tensor, h: i64, w: i64, ac: bool) -> f64 {
        let fused = ordinal_levels_fused(z, h, w, ac);
        let plain = crate::ordinal::ordinal_levels(z, h, w, ac);
        assert_eq!(fused.size(), plain.size());
        fused
            .eq_tensor(&plain)
            .to_kind(Kind::Double)
            .mean(Kind::Double)
            .double_value(&[])
    }

    #[test]
    fn fused_levels_equal_the_upsampled_ones_on_99_99_percent_of_pixels() {
        let mut seed = 3u64 << 20 | 1;
        // A head's output size for 350x800 and odd, non-integer ratios; both corner rules.
        for (b, k, h, w, hh, ww) in [(2, 80, 88, 200, 350, 800), (1, 7, 5, 9, 23, 41)] {
            for ac in [false, true] {
                let z = (crate::test_rng::uniform(&[b, k, h, w], &mut seed) - 0.5) * 12.0;
                let a = agreement(&z, hh, ww, ac);
                assert!(a >= 0.9999, "{b}x{k}x{h}x{w} → {hh}x{ww}, ac {ac}: {a}");
            }
        }
    }

    #[test]
    fn same_size_and_one_pixel_outputs_are_plain_counts() {
        let z = Tensor::randn([1, 5, 4, 6], (Kind::Float, Device::Cpu));
        assert_eq!(agreement(&z, 4, 6, false), 1.0, "identity taps");
        assert_eq!(
            agreement(&z, 1, 1, true),
            1.0,
            "align_corners with one output pixel"
        );
    }

    #[test]
    fn taps_follow_pytorchs_source_index() {
        // 2 → 4, align_corners false: src = (d + 0.5)/2 − 0.5 clamped at 0 → 0, 0.25, 0.75, 1.25.
        let t = taps(2, 4, false);
        assert_eq!((t[0].i0, t[0].i1, t[0].l1), (0, 1, 0.0));
        assert_eq!((t[1].i0, t[1].l1), (0, 0.25));
        assert_eq!(
            (t[3].i0, t[3].i1, t[3].l0),
            (1, 1, 0.75),
            "the last row clamps"
        );
        let t = taps(3, 5, true);
        assert_eq!((t[4].i0, t[4].i1, t[4].l1), (2, 2, 0.0));
    }
}
