//! Spacing-increasing discretisation (SPEC §7): thresholds, labels, bin centres.

use tch::{Kind, Tensor};

use depthsense_config::SidConfig;

/// Threshold t_i = exp(ln α + ln(β/α)·i/K) in metres; defined for any real i (SPEC §7),
/// so t_{K+1} (needed to decode level K) extends the same progression.
pub fn threshold_m(sid: &SidConfig, i: f64) -> f64 {
    (sid.alpha_m.ln() + (sid.beta_m / sid.alpha_m).ln() * i / sid.bins as f64).exp()
}

/// All thresholds t_0..t_K.
pub fn thresholds_m(sid: &SidConfig) -> Vec<f64> {
    (0..=sid.bins).map(|i| threshold_m(sid, i as f64)).collect()
}

/// Label l = ⌊K·ln(d/α)/ln(β/α)⌋ clamped to 0..K (SPEC §7).
pub fn label_of_depth(sid: &SidConfig, depth_m: f64) -> i64 {
    if depth_m.is_nan() || depth_m <= sid.alpha_m {
        return 0;
    }
    let l =
        (sid.bins as f64 * (depth_m / sid.alpha_m).ln() / (sid.beta_m / sid.alpha_m).ln()).floor();
    (l as i64).clamp(0, sid.bins)
}

/// Decoded depth of level l: (t_l + t_{l+1})/2 − decode offset (SPEC §7).
pub fn depth_of_level(sid: &SidConfig, level: i64) -> f64 {
    let l = level as f64;
    (threshold_m(sid, l) + threshold_m(sid, l + 1.0)) / 2.0 - sid.decode_offset_m
}

/// Labels of a depth tensor (any shape, metres) as int64 in 0..K; depths ≤ α (including the
/// 0 = invalid marker) get label 0, the caller masks invalid pixels.
pub fn labels(sid: &SidConfig, depth_m: &Tensor) -> Tensor {
    let k = sid.bins as f64;
    let scale = k / (sid.beta_m / sid.alpha_m).ln();
    let d = depth_m.to_kind(Kind::Float).clamp_min(sid.alpha_m);
    ((d / sid.alpha_m).log() * scale)
        .floor()
        .clamp(0.0, k)
        .to_kind(Kind::Int64)
}

/// Depth in metres of a tensor of (integer-valued) levels, any shape, float result.
pub fn levels_to_depth(sid: &SidConfig, level: &Tensor) -> Tensor {
    let step = (sid.beta_m / sid.alpha_m).ln() / sid.bins as f64;
    let l = level.to_kind(Kind::Float);
    let lo = (&l * step + sid.alpha_m.ln()).exp();
    let hi = ((&l + 1.0) * step + sid.alpha_m.ln()).exp();
    (lo + hi) / 2.0 - sid.decode_offset_m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thresholds_span_alpha_beta() {
        let s = SidConfig::default();
        let t = thresholds_m(&s);
        assert_eq!(t.len(), 81);
        assert!((t[0] - 1.0).abs() < 1e-12);
        assert!((t[80] - 80.0).abs() < 1e-9);
        // spacing increases
        assert!(t.windows(3).all(|w| w[2] - w[1] > w[1] - w[0]));
    }

    #[test]
    fn every_depth_decodes_into_its_own_bin() {
        let s = SidConfig::default();
        let mut d = 1.0;
        while d <= 80.0 {
            let l = label_of_depth(&s, d);
            let back = depth_of_level(&s, l);
            assert_eq!(
                label_of_depth(&s, back),
                l,
                "depth {d} label {l} decoded {back}"
            );
            assert!(back >= threshold_m(&s, l as f64) && back < threshold_m(&s, l as f64 + 1.0));
            d += 0.013;
        }
        assert_eq!(label_of_depth(&s, 80.0), 80);
        assert_eq!(label_of_depth(&s, 0.0), 0);
        assert_eq!(label_of_depth(&s, 500.0), 80);
    }

    #[test]
    fn tensor_labels_match_scalar_labels() {
        let s = SidConfig::default();
        let ds: Vec<f32> = (0..2000).map(|i| 0.5 + i as f32 * 0.05).collect();
        let t = Tensor::from_slice(&ds);
        let l = Vec::<i64>::try_from(labels(&s, &t)).unwrap();
        let dec = Vec::<f32>::try_from(levels_to_depth(&s, &labels(&s, &t))).unwrap();
        for (i, d) in ds.iter().enumerate() {
            let want = label_of_depth(&s, *d as f64);
            // f32 vs f64 logs may differ only at exact thresholds
            assert!((l[i] - want).abs() <= 1, "{d}: {} vs {want}", l[i]);
            assert!((dec[i] as f64 - depth_of_level(&s, l[i])).abs() < 1e-3);
        }
    }
}
