//! Golden tests on hand-computed arrays (values worked out by hand in the comments).

use super::*;
use crate::tables;

fn close(a: f64, b: f64, tol: f64) {
    assert!((a - b).abs() <= tol, "{a} vs {b} (tol {tol})");
}

// Image A (day): gt = [10, 20, 0, 60, 90], pred = [12, 20, 5, 30, 0.5],
// low-height mask = [T, F, F, T, F].
const GT_A: [f32; 5] = [10.0, 20.0, 0.0, 60.0, 90.0];
const PRED_A: [f32; 5] = [12.0, 20.0, 5.0, 30.0, 0.5];
const LOW_A: [bool; 5] = [true, false, false, true, false];
// Image B (night): gt = [5], pred = [10].
const GT_B: [f32; 1] = [5.0];
const PRED_B: [f32; 1] = [10.0];

fn img_a() -> EvalImage<'static> {
    EvalImage {
        pred_m: &PRED_A,
        gt_m: &GT_A,
        lowheight: Some(&LOW_A),
        conditions: &["day"],
    }
}

fn img_b() -> EvalImage<'static> {
    EvalImage {
        pred_m: &PRED_B,
        gt_m: &GT_B,
        lowheight: None,
        conditions: &["night"],
    }
}

#[test]
fn every_metric_cap50_mask() {
    // Cap 50 keeps (10,12) and (20,20); 60 and 90 exceed the cap, 0 is no data.
    // (10,12): ratio 1.2, |d| 2, d²=4, AbsRel .2, SqRel .4, (ln10−ln12)² = 0.0332411500
    let rep = evaluate(&[img_a()], &EvalConfig::default()).unwrap();
    let r = rep.row("combined", "full", 50.0).unwrap();
    assert_eq!((r.n_images, r.n_pixels), (1, 2));
    let m = r.metrics;
    close(m.delta1, 1.0, 1e-12);
    close(m.delta2, 1.0, 1e-12);
    close(m.delta3, 1.0, 1e-12);
    close(m.abs_rel, 0.1, 1e-12);
    close(m.sq_rel, 0.2, 1e-12);
    close(m.rmse, 2f64.sqrt(), 1e-12);
    close(m.rmse_log, (0.033_241_150_0_f64 / 2.0).sqrt(), 1e-9);
    close(m.mae, 1.0, 1e-12);
}

#[test]
fn every_metric_cap70_and_80_mask() {
    // Cap 70 adds (60,30): ratio 2 ≥ 1.25³ = 1.953125 → fails δ1..δ3; d² = 900,
    // AbsRel .5, SqRel 15, (ln 2)² = 0.480453014. n = 3.
    let rep = evaluate(&[img_a()], &EvalConfig::default()).unwrap();
    for cap in [70.0, 80.0] {
        // 90 m exceeds 80 too: cap 80 equals cap 70 here.
        let r = rep.row("combined", "full", cap).unwrap();
        assert_eq!(r.n_pixels, 3);
        let m = r.metrics;
        close(m.delta1, 2.0 / 3.0, 1e-12);
        close(m.delta2, 2.0 / 3.0, 1e-12);
        close(m.delta3, 2.0 / 3.0, 1e-12);
        close(m.abs_rel, 0.7 / 3.0, 1e-12);
        close(m.sq_rel, 15.4 / 3.0, 1e-12);
        close(m.rmse, (904.0f64 / 3.0).sqrt(), 1e-9);
        close(m.rmse, 17.358_955, 1e-5);
        close(
            m.rmse_log,
            ((0.033_241_150_0 + 0.480_453_014) / 3.0f64).sqrt(),
            1e-9,
        );
        close(m.mae, 32.0 / 3.0, 1e-12);
    }
}

#[test]
fn delta_thresholds_are_strict_and_powers_of_1_25() {
    // ratio exactly 1.25 is not < 1.25; 1.5 passes δ2 (1.5625) not δ1; 1.9 passes δ3 only.
    let gt = [10.0f32, 10.0, 10.0, 10.0];
    let pred = [12.5f32, 15.0, 19.0, 5.2]; // 10/5.2 = 1.923 → δ3
    let rep = evaluate(
        &[EvalImage {
            pred_m: &pred,
            gt_m: &gt,
            lowheight: None,
            conditions: &[],
        }],
        &EvalConfig::default(),
    )
    .unwrap();
    let m = rep.row("combined", "full", 80.0).unwrap().metrics;
    close(m.delta1, 0.0, 1e-12);
    close(m.delta2, 0.5, 1e-12); // 1.25 and 1.5 pass δ2
    close(m.delta3, 1.0, 1e-12);
}

#[test]
fn clamp_protocol_keeps_far_pixels_and_clamps_both() {
    // Cap 50 under clamp: (10,12), (20,20), (min(60,50)=50, 30), (50, clip(0.5)=1 → 1).
    let cfg = EvalConfig {
        protocol: Protocol::Clamp,
        ..EvalConfig::default()
    };
    let rep = evaluate(&[img_a()], &cfg).unwrap();
    let r = rep.row("combined", "full", 50.0).unwrap();
    assert_eq!(r.n_pixels, 4);
    // MAE = (2 + 0 + 20 + 49)/4 = 17.75; RMSE = sqrt((4 + 0 + 400 + 2401)/4) = sqrt(701.25)
    close(r.metrics.mae, 17.75, 1e-12);
    close(r.metrics.rmse, 701.25f64.sqrt(), 1e-9);
    // δ1: (10,12) and (20,20) pass; 50/30 = 1.67 and 50/1 fail.
    close(r.metrics.delta1, 0.5, 1e-12);
    // Cap 80 under clamp: (60,30) unchanged, (90→80, 1).
    let r80 = rep.row("combined", "full", 80.0).unwrap();
    assert_eq!(r80.n_pixels, 4);
    close(r80.metrics.mae, (2.0 + 0.0 + 30.0 + 79.0) / 4.0, 1e-12);
}

#[test]
fn prediction_clipped_to_alpha_beta() {
    // gt 2, pred 0.1 → clipped to 1 → |d| = 1; gt 79, pred 500 → 80 → |d| = 1; NaN → 80.
    let gt = [2.0f32, 79.0, 79.0];
    let pred = [0.1f32, 500.0, f32::NAN];
    let rep = evaluate(
        &[EvalImage {
            pred_m: &pred,
            gt_m: &gt,
            lowheight: None,
            conditions: &[],
        }],
        &EvalConfig::default(),
    )
    .unwrap();
    close(
        rep.row("combined", "full", 80.0).unwrap().metrics.mae,
        1.0,
        1e-12,
    );
}

#[test]
fn per_image_vs_pooled_aggregation() {
    // A at cap 80: RMSE sqrt(904/3) = 17.358955, δ1 2/3; B: RMSE 5, δ1 0.
    let imgs = [img_a(), img_b()];
    let per_image = evaluate(&imgs, &EvalConfig::default()).unwrap();
    let r = per_image.row("combined", "full", 80.0).unwrap();
    assert_eq!((r.n_images, r.n_pixels), (2, 4));
    close(r.metrics.rmse, ((904.0f64 / 3.0).sqrt() + 5.0) / 2.0, 1e-9);
    close(r.metrics.delta1, (2.0 / 3.0) / 2.0, 1e-12);
    close(r.metrics.mae, (32.0 / 3.0 + 5.0) / 2.0, 1e-12);
    let pooled = evaluate(
        &imgs,
        &EvalConfig {
            aggregate: Aggregate::Pooled,
            ..EvalConfig::default()
        },
    )
    .unwrap();
    let r = pooled.row("combined", "full", 80.0).unwrap();
    // Pooled: Σd² = 904 + 25 = 929 over 4 px; δ1 2/4; MAE 37/4.
    close(r.metrics.rmse, (929.0f64 / 4.0).sqrt(), 1e-9);
    close(r.metrics.delta1, 0.5, 1e-12);
    close(r.metrics.mae, 37.0 / 4.0, 1e-12);
}

#[test]
fn condition_and_region_rows() {
    let rep = evaluate(&[img_a(), img_b()], &EvalConfig::default()).unwrap();
    assert_eq!(rep.images_seen, 2);
    assert_eq!(rep.rows.len(), 4 * 2 * 3);
    let day = rep.row("day", "full", 80.0).unwrap();
    assert_eq!((day.n_images, day.n_pixels), (1, 3));
    let night = rep.row("night", "full", 80.0).unwrap();
    assert_eq!((night.n_images, night.n_pixels), (1, 1));
    close(night.metrics.rmse, 5.0, 1e-12);
    let rain = rep.row("rain", "full", 80.0).unwrap();
    assert_eq!((rain.n_images, rain.n_pixels), (0, 0));
    // Low-height (A only): (10,12) and (60,30) at cap 80 → MAE 16, RMSE sqrt(452).
    let low = rep.row("combined", "lowheight", 80.0).unwrap();
    assert_eq!((low.n_images, low.n_pixels), (1, 2));
    close(low.metrics.mae, 16.0, 1e-12);
    close(low.metrics.rmse, 452f64.sqrt(), 1e-9);
    // At cap 50 only (10,12) remains in the low-height region.
    let low50 = rep.row("combined", "lowheight", 50.0).unwrap();
    assert_eq!(low50.n_pixels, 1);
    assert_eq!(rep.headline().unwrap().cap_m, 80.0);
}

#[test]
fn night_rain_scene_counts_in_both_rows() {
    let rep = evaluate(
        &[EvalImage {
            pred_m: &PRED_B,
            gt_m: &GT_B,
            lowheight: None,
            conditions: &["night", "rain"],
        }],
        &EvalConfig::default(),
    )
    .unwrap();
    assert_eq!(rep.row("night", "full", 80.0).unwrap().n_images, 1);
    assert_eq!(rep.row("rain", "full", 80.0).unwrap().n_images, 1);
    assert_eq!(rep.row("day", "full", 80.0).unwrap().n_images, 0);
}

#[test]
fn image_without_valid_pixels_does_not_count() {
    let gt = [0.0f32, 90.0];
    let pred = [3.0f32, 3.0];
    let rep = evaluate(
        &[
            img_b(),
            EvalImage {
                pred_m: &pred,
                gt_m: &gt,
                lowheight: None,
                conditions: &["night"],
            },
        ],
        &EvalConfig::default(),
    )
    .unwrap();
    let r = rep.row("combined", "full", 80.0).unwrap();
    assert_eq!(r.n_images, 1);
    close(r.metrics.rmse, 5.0, 1e-12);
}

#[test]
fn size_mismatch_and_bad_config_are_errors() {
    let gt = [1.0f32; 3];
    let pred = [1.0f32; 2];
    let err = evaluate(
        &[EvalImage {
            pred_m: &pred,
            gt_m: &gt,
            lowheight: None,
            conditions: &[],
        }],
        &EvalConfig::default(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("prediction has 2 values"), "{err}");
    let bad = EvalConfig {
        caps_m: vec![],
        ..EvalConfig::default()
    };
    assert!(Evaluator::new(bad).is_err());
    assert!("bogus".parse::<Protocol>().is_err());
    assert_eq!("clamp".parse::<Protocol>().unwrap(), Protocol::Clamp);
    assert_eq!("pooled".parse::<Aggregate>().unwrap(), Aggregate::Pooled);
}

#[test]
fn perfect_prediction_is_perfect() {
    let gt: Vec<f32> = (3..200).map(|i| i as f32 * 0.4).collect();
    let rep = evaluate(
        &[EvalImage {
            pred_m: &gt,
            gt_m: &gt,
            lowheight: None,
            conditions: &["rain"],
        }],
        &EvalConfig::default(),
    )
    .unwrap();
    let m = rep.row("rain", "full", 80.0).unwrap().metrics;
    assert_eq!(
        (m.delta1, m.rmse, m.abs_rel, m.rmse_log),
        (1.0, 0.0, 0.0, 0.0)
    );
}

#[test]
fn tables_layout_and_values() {
    let rep = evaluate(&[img_a(), img_b()], &EvalConfig::default()).unwrap();
    let models = [("rgb", &rep), ("fusion", &rep)];
    let main = tables::main_table(&models);
    assert_eq!(main.rows.len(), 8);
    // combined row of the first model: 2 images, 4 pixels, δ1 0.333, RMSE 11.179
    assert_eq!(
        main.rows[0][..4],
        ["rgb", "combined", "2", "4"].map(String::from)
    );
    assert_eq!(main.rows[0][4], "0.333");
    assert_eq!(main.rows[0][5], "11.179");
    // rain row has no images: dashes
    assert_eq!(main.rows[3][4], "–");
    let dist = tables::distance_table(&models);
    assert_eq!(dist.rows.len(), 6);
    // cap 50 of image A only… plus B (5 m): per-image MAE (1 + 5)/2 = 3 m = 3000 mm
    assert_eq!(dist.rows[0][4], "3000");
    let md = tables::markdown_report(&models);
    assert!(md.contains("| model | condition | images | pixels | δ1 | RMSE (m) | AbsRel |"));
    assert!(md.contains("Protocol `mask`, aggregation `image`"));
    let csv = tables::csv_report(&models);
    assert!(csv.contains("model,region,images,pixels,δ1,δ2,δ3,RMSE (m),AbsRel,RMSE_log\n"));
    assert!(csv
        .lines()
        .any(|l| l == "fusion,low-height,1,2,0.500,0.500,0.500,21.260,0.350,0.507"));
}

#[test]
fn radarnet_protocol_strict_cap_no_clip_per_image() {
    // gt = [10, 50, 60, 0], pred = [0.5, 40, 60, 3], cap 50: only pixel 0 is kept
    // (50 is not < 50; 60 beyond; 0 has no GT). The prediction 0.5 is not clipped to 1:
    // |10 − 0.5| = 9.5.
    let gt = [10.0f32, 50.0, 60.0, 0.0];
    let pred = [0.5f32, 40.0, 60.0, 3.0];
    let img = EvalImage {
        pred_m: &pred,
        gt_m: &gt,
        lowheight: None,
        conditions: &["day"],
    };
    let cfg = EvalConfig {
        caps_m: vec![50.0, 80.0],
        protocol: Protocol::Radarnet,
        ..EvalConfig::default()
    };
    let r = evaluate(&[img], &cfg).unwrap();
    let row = r.row("combined", "full", 50.0).unwrap();
    assert_eq!(row.n_pixels, 1);
    close(row.metrics.mae, 9.5, 1e-12);
    // cap 80: pixels 0, 1, 2 → errors 9.5, 10, 0 → MAE 19.5 / 3
    let row = r.row("combined", "full", 80.0).unwrap();
    assert_eq!(row.n_pixels, 3);
    close(row.metrics.mae, 19.5 / 3.0, 1e-12);
    // the mask protocol keeps GT = 50 at cap 50 and clips 0.5 to 1
    let m = evaluate(
        &[img],
        &EvalConfig {
            caps_m: vec![50.0],
            ..EvalConfig::default()
        },
    )
    .unwrap();
    let row = m.row("combined", "full", 50.0).unwrap();
    assert_eq!(row.n_pixels, 2);
    close(row.metrics.mae, (9.0 + 10.0) / 2.0, 1e-12);
    assert_eq!("radarnet".parse::<Protocol>().unwrap(), Protocol::Radarnet);
    let pooled = EvalConfig {
        aggregate: Aggregate::Pooled,
        ..cfg
    };
    assert!(Evaluator::new(pooled).is_err());
}

// Added after the mutation run of issue 23 (BENCHMARKS.md): the strict δ2/δ3 edges, both
// aggregations with every metric over two images, the configuration bounds and the CSV quoting.

#[test]
fn delta2_and_delta3_edges_are_strict() {
    // 25/16 = 1.5625 = 1.25² and 125/64 = 1.953125 = 1.25³ exactly (binary fractions): a
    // ratio equal to the threshold is outside (SPEC §9: max(ŷ/y, y/ŷ) < 1.25^n).
    let gt = [16.0f32, 64.0];
    let pred = [25.0f32, 125.0];
    let rep = evaluate(
        &[EvalImage {
            pred_m: &pred,
            gt_m: &gt,
            lowheight: None,
            conditions: &[],
        }],
        &EvalConfig {
            clip_max_m: 200.0,
            caps_m: vec![80.0],
            ..EvalConfig::default()
        },
    )
    .unwrap();
    let m = rep.row("combined", "full", 80.0).unwrap().metrics;
    close(m.delta2, 0.0, 0.0); // 1.5625 not < 1.5625; 1.953 not < 1.5625
    close(m.delta3, 0.5, 0.0); // 1.5625 < 1.953125; 1.953125 not < 1.953125
}

/// Image A: gt [10, 20], pred [12, 10]; image B: gt [5], pred [10].
/// Per pixel (y, ŷ): ratio, |d|, d², AbsRel, SqRel, (ln y − ln ŷ)²
///   A1 (10, 12): 1.2, 2, 4, 0.2, 0.4, ln²(10/12)
///   A2 (20, 10): 2.0, 10, 100, 0.5, 5, ln²2
///   B1 (5, 10):  2.0, 5, 25, 1.0, 5, ln²2
fn two_images() -> [EvalImage<'static>; 2] {
    const GA: [f32; 2] = [10.0, 20.0];
    const PA: [f32; 2] = [12.0, 10.0];
    const GB: [f32; 1] = [5.0];
    const PB: [f32; 1] = [10.0];
    [
        EvalImage {
            pred_m: &PA,
            gt_m: &GA,
            lowheight: None,
            conditions: &["day"],
        },
        EvalImage {
            pred_m: &PB,
            gt_m: &GB,
            lowheight: None,
            conditions: &["day"],
        },
    ]
}

#[test]
fn every_metric_under_both_aggregations() {
    let l1 = (10f64 / 12.0).ln().powi(2);
    let l2 = 2f64.ln().powi(2);
    let check = |m: Metrics, want: [f64; 8]| {
        let got = [
            m.delta1, m.delta2, m.delta3, m.abs_rel, m.sq_rel, m.rmse, m.rmse_log, m.mae,
        ];
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            assert!((g - w).abs() < 1e-12, "metric {i}: {g} vs {w} ({m:?})");
        }
    };
    // Per image, then the mean over the two images (SPEC §9, RadarNet):
    //   A: δ 1/2 each, AbsRel .35, SqRel 2.7, RMSE √52, RMSE_log √((l1+l2)/2), MAE 6
    //   B: δ 0, AbsRel 1, SqRel 5, RMSE 5, RMSE_log ln 2, MAE 5
    let image = evaluate(&two_images(), &EvalConfig::default()).unwrap();
    let r = image.row("day", "full", 80.0).unwrap();
    assert_eq!((r.n_images, r.n_pixels), (2, 3));
    check(
        r.metrics,
        [
            0.25,
            0.25,
            0.25,
            (0.35 + 1.0) / 2.0,
            (2.7 + 5.0) / 2.0,
            (52f64.sqrt() + 5.0) / 2.0,
            (((l1 + l2) / 2.0).sqrt() + 2f64.ln()) / 2.0,
            (6.0 + 5.0) / 2.0,
        ],
    );
    // Pooled over the 3 pixels (DORN): δ 1/3 each, AbsRel 1.7/3, SqRel 10.4/3, RMSE √(129/3),
    // RMSE_log √((l1 + 2·l2)/3), MAE 17/3
    let cfg = EvalConfig {
        aggregate: Aggregate::Pooled,
        ..EvalConfig::default()
    };
    let pooled = evaluate(&two_images(), &cfg).unwrap();
    check(
        pooled.row("day", "full", 80.0).unwrap().metrics,
        [
            1.0 / 3.0,
            1.0 / 3.0,
            1.0 / 3.0,
            1.7 / 3.0,
            10.4 / 3.0,
            43f64.sqrt(),
            ((l1 + 2.0 * l2) / 3.0).sqrt(),
            17.0 / 3.0,
        ],
    );
    let ev = Evaluator::new(cfg.clone()).unwrap();
    assert_eq!(ev.config(), &cfg);
}

#[test]
fn caps_and_clip_range_must_be_positive_and_ordered() {
    let bad = |c: EvalConfig| Evaluator::new(c).is_err();
    let d = EvalConfig::default;
    for caps in [
        vec![0.0],
        vec![80.0, -1.0],
        vec![f64::NAN],
        vec![f64::INFINITY],
    ] {
        assert!(
            bad(EvalConfig {
                caps_m: caps.clone(),
                ..d()
            }),
            "{caps:?}"
        );
    }
    assert!(bad(EvalConfig {
        clip_min_m: 0.0,
        ..d()
    }));
    assert!(bad(EvalConfig {
        clip_min_m: 80.0,
        clip_max_m: 80.0,
        ..d()
    }));
    assert!(bad(EvalConfig {
        clip_min_m: 2.0,
        clip_max_m: 1.0,
        ..d()
    }));
    assert!(!bad(EvalConfig {
        caps_m: vec![1e-3],
        clip_min_m: 1e-3,
        clip_max_m: 2e-3,
        ..d()
    }));
}

#[test]
fn csv_fields_with_commas_quotes_or_newlines_are_quoted() {
    let t = tables::Table {
        title: "t".into(),
        header: vec!["a,b".into(), "plain".into()],
        rows: vec![vec!["say \"hi\"".into(), "two\nlines".into()]],
    };
    assert_eq!(
        t.to_csv(),
        "\"a,b\",plain\n\"say \"\"hi\"\"\",\"two\nlines\"\n"
    );
}

#[test]
fn a_missing_row_fills_every_column_and_tables_are_separated_once() {
    let rep = evaluate(&[img_a()], &EvalConfig::default()).unwrap();
    let mut without_night = rep.clone();
    without_night.rows.retain(|r| r.condition != "night");
    let models = [("a", &rep), ("b", &without_night)];
    let main = tables::main_table(&models);
    for row in &main.rows {
        assert_eq!(row.len(), main.header.len(), "{row:?}");
    }
    let night_b = main
        .rows
        .iter()
        .find(|r| r[0] == "b" && r[1] == "night")
        .unwrap();
    assert!(night_b[2..].iter().all(|c| c == "–"), "{night_b:?}");
    let csv = tables::csv_report(&models);
    assert!(csv.starts_with("# "), "{csv}");
    assert_eq!(
        csv.matches("\n\n# ").count(),
        2,
        "three tables, one blank line between each"
    );
}
