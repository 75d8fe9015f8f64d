//! SID labels, the ordinal loss, its gradient and the decoded depth against SPEC §7's formulas,
//! with goldens computed by hand (issue 23) — never from `sid::labels` / `levels_to_depth`.
//!
//! SPEC §7: K bins between α and β, t_i = α·(β/α)^(i/K); label l = ⌊K·ln(d/α)/ln(β/α)⌋ clamped
//! to 0..K; y_k = [k < l]; P_k = σ(b_k − a_k) with channel 2k = a_k, 2k+1 = b_k (§6.1);
//! loss = −mean over valid pixels of Σ_k y_k ln P_k + (1 − y_k) ln(1 − P_k);
//! decode l̂ = Σ_k [P_k ≥ 0.5], depth = (t_l̂ + t_{l̂+1})/2.

use depthsense_config::SidConfig;
use depthsense_model::ordinal::{
    self, ordinal_decode, ordinal_loss, ordinal_loss_dense, pair_differences,
};
use depthsense_model::sid::{depth_of_level, label_of_depth, labels, levels_to_depth};
use tch::{Device, Kind, Tensor};

/// The paper's discretisation: K = 80, α = 1 m, β = 80 m.
fn paper() -> SidConfig {
    SidConfig::default()
}

/// A discretisation small enough to do by hand: K = 4, α = 1 m, β = 16 m, so the thresholds
/// are t = 1, 2, 4, 8, 16 m (and t_5 = 32 m).
fn hand() -> SidConfig {
    SidConfig {
        bins: 4,
        alpha_m: 1.0,
        beta_m: 16.0,
        decode_offset_m: 0.0,
    }
}

fn f32s(t: &Tensor) -> Vec<f32> {
    Vec::<f32>::try_from(t.flatten(0, -1).to_kind(Kind::Float)).unwrap()
}

fn i64s(t: &Tensor) -> Vec<i64> {
    Vec::<i64>::try_from(t.flatten(0, -1).to_kind(Kind::Int64)).unwrap()
}

/// (depth m, label) for K = 80, α = 1, β = 80: 80·ln d / ln 80 with ln 80 = 4.382027, worked out
/// by hand, e.g. d = 9: 80·2.197225/4.382027 = 40.113 → 40.
const PAPER_LABELS: [(f64, i64); 10] = [
    (0.5, 0),    // below α: −12.65, clamped to 0
    (2.0, 12),   // 12.654
    (4.0, 25),   // 25.309
    (9.0, 40),   // 40.113
    (10.0, 42),  // 42.037
    (30.0, 62),  // 62.094
    (50.0, 71),  // 71.419
    (79.9, 79),  // 79.977
    (100.0, 80), // 84.07, clamped to K
    (250.0, 80), // clamped to K
];

#[test]
fn labels_equal_the_hand_computed_ones() {
    let sid = paper();
    for (d, l) in PAPER_LABELS {
        assert_eq!(label_of_depth(&sid, d), l, "label of {d} m");
    }
    // The tensor path (float32, as in training) gives exactly the same labels.
    let d: Vec<f32> = PAPER_LABELS.iter().map(|(d, _)| *d as f32).collect();
    let got = i64s(&labels(&sid, &Tensor::from_slice(&d)));
    let want: Vec<i64> = PAPER_LABELS.iter().map(|(_, l)| *l).collect();
    assert_eq!(got, want);
    // By hand for K = 4 (thresholds 1, 2, 4, 8, 16 m): 5 m lies in [4, 8) → 2.
    assert_eq!(label_of_depth(&hand(), 5.0), 2);
    assert_eq!(label_of_depth(&hand(), 15.9), 3);
    assert_eq!(label_of_depth(&hand(), 1.5), 0);
}

/// Away from bin edges the label is exactly the bin: at every geometric bin centre
/// α·(β/α)^((i+½)/K) and 0.01 % inside both edges of every bin, for all 80 bins.
#[test]
fn labels_are_exact_inside_every_bin() {
    let sid = paper();
    let t = |x: f64| 80f64.powf(x / 80.0); // α = 1: t_x = 80^(x/K), written with powf
    let mut depths = Vec::new();
    let mut want = Vec::new();
    for i in 0..80 {
        for d in [
            t(i as f64 + 0.5),
            t(i as f64) * 1.0001,
            t(i as f64 + 1.0) * 0.9999,
        ] {
            assert_eq!(label_of_depth(&sid, d), i, "{d} m in bin {i}");
            depths.push(d as f32);
            want.push(i);
        }
    }
    assert_eq!(i64s(&labels(&sid, &Tensor::from_slice(&depths))), want);
}

/// One valid pixel, K = 4, depth 5 m (label 2, y = [1, 1, 0, 0]), logit pairs chosen so that
/// z = b − a = [2, −1, 0.5, −3]. By hand:
/// loss = ln(1+e^−2) + ln(1+e^1) + ln(1+e^0.5) + ln(1+e^−3)
///      = 0.126928 + 1.313262 + 0.974077 + 0.048587 = 2.462854;
/// ∂loss/∂z_k = σ(z_k) − y_k = [−0.119203, −0.731059, 0.622459, 0.047426],
/// ∂/∂b_k = ∂/∂z_k and ∂/∂a_k = −∂/∂z_k. Decode: z ≥ 0 at k = 0, 2 → l̂ = 2 → (4 + 8)/2 = 6 m.
#[test]
fn one_pixel_loss_gradient_and_decode_by_hand() {
    let sid = hand();
    // channel 2k = a_k, 2k+1 = b_k
    let pairs: [(f64, f64); 4] = [(0.5, 2.5), (1.0, 0.0), (-0.25, 0.25), (2.0, -1.0)];
    let flat: Vec<f64> = pairs.iter().flat_map(|(a, b)| [*a, *b]).collect();
    let logits = Tensor::from_slice(&flat)
        .view([1, 8, 1, 1])
        .set_requires_grad(true);
    let z = pair_differences(&logits);
    assert_eq!(f32s(&z), vec![2.0, -1.0, 0.5, -3.0]);
    let target = Tensor::from_slice(&[5.0f64]).view([1, 1, 1, 1]);
    let loss = ordinal_loss(&z, &target, &sid, false);
    assert!((loss.double_value(&[]) - 2.462854).abs() < 1e-6, "{loss}");
    let dense = ordinal_loss_dense(&z, &target, &sid, false).double_value(&[]);
    assert!((dense - 2.462854).abs() < 1e-6, "{dense}");
    loss.backward();
    let g = Vec::<f64>::try_from(logits.grad().flatten(0, -1)).unwrap();
    let dz = [-0.119203, -0.731059, 0.622459, 0.047426];
    for k in 0..4 {
        assert!((g[2 * k] + dz[k]).abs() < 1e-6, "∂/∂a_{k}: {g:?}");
        assert!((g[2 * k + 1] - dz[k]).abs() < 1e-6, "∂/∂b_{k}: {g:?}");
    }
    let depth = ordinal_decode(&z.detach(), &sid, 1, 1, false);
    assert_eq!(f32s(&depth), vec![6.0]);
    assert!((depth_of_level(&sid, 2) - 6.0).abs() < 1e-12);
}

/// The mean runs over valid pixels only: a second valid pixel at 1.5 m (label 0, y = 0) with
/// z = −1 everywhere adds 4·ln(1 + e^−1) = 4·0.313262 = 1.253047; an invalid pixel (0 m) adds
/// nothing. Mean = (2.462854 + 1.253047)/2 = 1.857950.
#[test]
fn loss_is_the_mean_over_valid_pixels() {
    let sid = hand();
    let z = Tensor::from_slice(&[
        2.0f64, -1.0, 0.5, -3.0, -1.0, -1.0, -1.0, -1.0, 9.0, 9.0, 9.0, 9.0,
    ])
    .view([3, 4])
    .transpose(0, 1)
    .contiguous()
    .view([1, 4, 1, 3]);
    let target = Tensor::from_slice(&[5.0f64, 1.5, 0.0]).view([1, 1, 1, 3]);
    let loss = ordinal_loss(&z, &target, &sid, false).double_value(&[]);
    assert!((loss - 1.857950).abs() < 1e-6, "{loss}");
}

/// Decoded depth is the bin centre (t_l̂ + t_{l̂+1})/2 for every level of the paper's
/// discretisation (t written with powf), minus the configured DORN-radar offset.
#[test]
fn decoded_depth_is_the_bin_centre() {
    let mut sid = paper();
    let t = |x: f64| 80f64.powf(x / 80.0);
    let levels: Vec<i64> = (0..=80).collect();
    let got = f32s(&levels_to_depth(&sid, &Tensor::from_slice(&levels)));
    for (l, g) in levels.iter().zip(&got) {
        let want = (t(*l as f64) + t(*l as f64 + 1.0)) / 2.0;
        assert!(
            ((*g as f64) - want).abs() <= 1e-5 * want,
            "level {l}: {g} vs {want}"
        );
        assert!((depth_of_level(&sid, *l) - want).abs() <= 1e-12 * want);
    }
    // level 40 by hand: (√80 + 80^(41/80))/2 = (8.944272 + 9.447864)/2 = 9.196068 m
    assert!((depth_of_level(&sid, 40) - 9.196068).abs() < 1e-6);
    sid.decode_offset_m = 0.3;
    assert!((depth_of_level(&sid, 40) - 8.896068).abs() < 1e-6);
    let with_offset = f32s(&levels_to_depth(&sid, &Tensor::from_slice(&[40i64])));
    assert!(
        (with_offset[0] as f64 - 8.896068).abs() < 1e-5,
        "{with_offset:?}"
    );
    // all K differences ≥ 0 → level K; ≥ 0 is inclusive (P = 0.5 counts, SPEC §7)
    let z = Tensor::zeros([1, 80, 1, 1], (Kind::Float, Device::Cpu));
    let d = ordinal_decode(&z, &paper(), 1, 1, false);
    assert!((f32s(&d)[0] as f64 - (80.0 + t(81.0)) / 2.0).abs() < 1e-3);
}

/// α ≠ 1 (the formulas divide depths by α and offset by ln α; with α = 1 those terms vanish):
/// K = 4, α = 2 m, β = 32 m, thresholds t = 2, 4, 8, 16, 32 m (t_5 = 64 m). By hand: 5 m →
/// ⌊4·ln(5/2)/ln 16⌋ = ⌊1.32⌋ = 1; 3 m → 0; 20 m → 3; level 1 decodes to (4 + 8)/2 = 6 m,
/// level 4 to (32 + 64)/2 = 48 m.
#[test]
fn a_first_threshold_other_than_one_metre() {
    let sid = SidConfig {
        bins: 4,
        alpha_m: 2.0,
        beta_m: 32.0,
        decode_offset_m: 0.0,
    };
    for (d, l) in [(5.0, 1), (3.0, 0), (20.0, 3), (1.0, 0), (40.0, 4)] {
        assert_eq!(label_of_depth(&sid, d), l, "{d} m");
    }
    let got = i64s(&labels(
        &sid,
        &Tensor::from_slice(&[5.0f32, 3.0, 20.0, 1.0, 40.0]),
    ));
    assert_eq!(got, vec![1, 0, 3, 0, 4]);
    let d = f32s(&levels_to_depth(&sid, &Tensor::from_slice(&[1i64, 4])));
    assert!(
        (d[0] - 6.0).abs() < 1e-5 && (d[1] - 48.0).abs() < 1e-4,
        "{d:?}"
    );
    assert!((depth_of_level(&sid, 1) - 6.0).abs() < 1e-12);
    assert!((depth_of_level(&sid, 4) - 48.0).abs() < 1e-12);
}

/// Decoding upsamples z bilinearly to the output size first (SPEC §7), also when only one of
/// the two sizes differs. z = [[−1, 1], [−1, 1]] (one bin) to 2x4 with align_corners: the
/// columns sample 0, ⅓, ⅔, 1 of the way → z = −1, −⅓, ⅓, 1 → levels 0, 0, 1, 1 on both rows;
/// to 4x2: every row equals [−1, 1] → levels 0, 1.
#[test]
fn decoding_upsamples_when_one_size_differs() {
    let z = Tensor::from_slice(&[-1.0f32, 1.0, -1.0, 1.0]).view([1, 1, 2, 2]);
    let wide = ordinal::ordinal_levels(&z, 2, 4, true);
    assert_eq!(wide.size(), [1, 1, 2, 4]);
    assert_eq!(i64s(&wide), vec![0, 0, 1, 1, 0, 0, 1, 1]);
    let tall = ordinal::ordinal_levels(&z, 4, 2, true);
    assert_eq!(tall.size(), [1, 1, 4, 2]);
    assert_eq!(i64s(&tall), vec![0, 1, 0, 1, 0, 1, 0, 1]);
    // align_corners = false: columns sample source x = −¼ (clamped to 0), ¼, ¾, 1¼ (clamped)
    // → z = −1, −½, ½, 1 → the same levels
    let wide = ordinal::ordinal_levels(&z, 2, 4, false);
    assert_eq!(i64s(&wide), vec![0, 0, 1, 1, 0, 0, 1, 1]);
    let up = ordinal::upsample(&z, 2, 4, false);
    assert!((f32s(&up.narrow(3, 1, 1))[0] + 0.5).abs() < 1e-6, "{up}");
}
