//! `experiment ablation` end to end on a toy prepared dataset (128x64 frames, `tiny` preset at
//! reduced widths): 2 variants × 2 seeds, outputs, mean/std from the per-seed numbers, skip of
//! finished runs, evaluation-only of trained runs, refusal of changed options; and the two
//! plotting helpers it (and the demo) use.

use crate::common;

use std::path::Path;

use common::{constant_depth_rmse, hidden, mtime, quick_runs};

use depthsense_config::variant::Variant;
use depthsense_dataset::outputs::BEST_CKPT;
use depthsense_experiments::ablation::{
    run_ablation, variant_models, AblationOptions, AblationResult, RunStatus, CSV_FILE, JSON_FILE,
    MD_FILE, PNG_FILE, RUN_EVAL_FILE,
};
use depthsense_experiments::Stat;
use depthsense_progress::Progress;
use depthsense_train::trainer::train;
use depthsense_viz::plot::{bar_chart_png, colorize_depth, picture_row_png};

fn opts(data: &Path, out: &Path) -> AblationOptions {
    AblationOptions {
        run: quick_runs(data),
        out: out.to_path_buf(),
        variants: vec![Variant::Rgb, Variant::LateSam],
        seeds: vec![0, 1],
        ..AblationOptions::default()
    }
}

#[test]
fn ablation_runs_reports_and_resumes() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    // 5 scenes × 2 samples: without split lists the trainer holds out one scene for
    // validation and one for test.
    depthsense_data::write_toy_dataset(&data, 5, 2, 128, 64, 3).unwrap();
    let out = tmp.path().join("abl");
    let o = opts(&data, &out);

    let r = run_ablation(&o, &hidden()).unwrap();
    for f in [MD_FILE, CSV_FILE, JSON_FILE, PNG_FILE] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let png = image::open(out.join(PNG_FILE)).unwrap();
    assert_eq!((png.width(), png.height()), (1000, 420));
    assert_eq!((r.trained, r.skipped), (4, 0));
    assert!(!r.partition.test_scenes.is_empty());
    assert!(r
        .partition
        .test_scenes
        .iter()
        .all(|s| !r.partition.val_scenes.contains(s)));

    // The JSON: 2 variants × 2 seeds with finite test RMSE.
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join(JSON_FILE)).unwrap()).unwrap();
    let runs = j["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 4);
    let mut pairs: Vec<(String, u64)> = runs
        .iter()
        .map(|x| {
            (
                x["variant"].as_str().unwrap().to_string(),
                x["seed"].as_u64().unwrap(),
            )
        })
        .collect();
    pairs.sort();
    assert_eq!(
        pairs,
        vec![
            ("late-sam".to_string(), 0),
            ("late-sam".to_string(), 1),
            ("rgb".to_string(), 0),
            ("rgb".to_string(), 1)
        ]
    );
    let headline = |x: &serde_json::Value, m: &str| -> f64 {
        x["rows"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["condition"] == "combined" && r["region"] == "full")
            .unwrap()[m]
            .as_f64()
            .unwrap()
    };
    let baseline = constant_depth_rmse(&data, &r.partition.test_scenes);
    for x in runs {
        let rmse = headline(x, "rmse");
        eprintln!(
            "{} seed {}: RMSE {rmse} m, constant-depth baseline {baseline} m",
            x["variant"], x["seed"]
        );
        assert!(rmse > 0.0 && rmse < baseline, "{x}");
        assert!(x["wall_seconds"].as_f64().unwrap() > 0.0);
        assert!(out
            .join("runs")
            .join(x["variant"].as_str().unwrap())
            .join(format!("seed{}", x["seed"]))
            .join(RUN_EVAL_FILE)
            .is_file());
    }
    // Mean and sample std (n − 1) of the summary follow from the per-seed numbers.
    for v in ["rgb", "late-sam"] {
        let s = j["summary"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["variant"] == v && s["condition"] == "combined" && s["region"] == "full")
            .unwrap();
        assert_eq!(s["n"], 2);
        for m in ["rmse", "delta1", "abs_rel", "mae"] {
            let xs: Vec<f64> = runs
                .iter()
                .filter(|x| x["variant"] == v)
                .map(|x| headline(x, m))
                .collect();
            let mean = (xs[0] + xs[1]) / 2.0;
            let std = ((xs[0] - mean).powi(2) + (xs[1] - mean).powi(2)).sqrt(); // / (2 − 1)
            let got_mean = s[m]["mean"].as_f64().unwrap();
            let got_std = s[m]["std"].as_f64().unwrap();
            assert!(
                (got_mean - mean).abs() <= 1e-12 * mean.abs().max(1.0),
                "{v} {m}"
            );
            assert!(
                (got_std - std).abs() <= 1e-9 * std.max(1e-6),
                "{v} {m}: {got_std} vs {std}"
            );
        }
    }
    // Seeds differ: the two runs of a variant are not the same network.
    let rgb: Vec<f64> = runs
        .iter()
        .filter(|x| x["variant"] == "rgb")
        .map(|x| headline(x, "rmse"))
        .collect();
    assert_ne!(rgb[0], rgb[1], "two seeds gave identical test RMSE");

    // Verdicts vs rgb in the Markdown; the CSV holds per-run and mean rows.
    let md = std::fs::read_to_string(out.join(MD_FILE)).unwrap();
    assert!(md.contains("late-sam vs rgb: RMSE "), "{md}");
    assert!(md.contains("two-sided paired t-test at 5 %"));
    assert!(md.contains(&r.partition.test_scenes[0]));
    let v = r.verdicts.iter().find(|v| v.metric == "rmse").unwrap();
    let (a, b) = (
        r.row("late-sam", "combined", "full").unwrap().rmse.unwrap(),
        r.row("rgb", "combined", "full").unwrap().rmse.unwrap(),
    );
    assert_eq!(v.difference, a.mean - b.mean);
    // The paired test, recomputed from the per-run records: seed by seed differences.
    let d: Vec<f64> = [0u64, 1]
        .iter()
        .map(|s| {
            let get = |name: &str| {
                headline(
                    runs.iter()
                        .find(|x| x["variant"] == name && x["seed"] == *s)
                        .unwrap(),
                    "rmse",
                )
            };
            get("late-sam") - get("rgb")
        })
        .collect();
    let p = v.paired.clone().unwrap();
    assert_eq!(v.paired_seeds, vec![0, 1]);
    let mean = (d[0] + d[1]) / 2.0;
    let se = (d[0] - d[1]).abs() / 2.0; // sd/√2 with sd = |d0 − d1|/√2
    assert!((p.mean_difference - mean).abs() < 1e-12);
    assert!((p.standard_error.unwrap() - se).abs() < 1e-9);
    assert_eq!(p.t_critical, Some(12.706));
    assert_eq!(p.significant, Some((mean / se).abs() > 12.706));
    // The paper's MER table appears with the late-sam-mer variant only; its cells are the
    // mean ± std over seeds of each run's full report (checked for δ2, which no other table has).
    assert!(depthsense_experiments::ablation::mer_table(&r, 80.0)
        .blocks
        .is_empty());
    let mut m = r.clone();
    for x in m.runs.iter_mut().filter(|x| x.variant == "late-sam") {
        x.variant = "late-sam-mer".into();
    }
    for (name, _) in m.models.iter_mut().filter(|(n, _)| n == "late-sam") {
        *name = "late-sam-mer".into();
    }
    let table = depthsense_experiments::ablation::mer_table(&m, 80.0).to_markdown();
    let d2: Vec<f64> = m
        .runs
        .iter()
        .filter(|x| x.variant == "late-sam-mer")
        .map(|x| {
            x.report
                .row("combined", "full", 80.0)
                .unwrap()
                .metrics
                .delta2
        })
        .collect();
    let stat = depthsense_experiments::Stat::of(&d2).unwrap();
    let line = table
        .lines()
        .find(|l| l.starts_with("| late-sam-mer | full | 2 |"))
        .unwrap_or_else(|| panic!("{table}"));
    assert_eq!(
        line.split(" | ").nth(4),
        Some(stat.fmt(3).as_str()),
        "{line}"
    );
    assert!(table.contains("| rgb | low-height | 2 |"), "{table}");

    let csv = std::fs::read_to_string(out.join(CSV_FILE)).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert!(lines[0].starts_with("kind,variant,seed,condition,region"));
    assert_eq!(
        lines
            .iter()
            .filter(|l| l.starts_with("run,") && l.contains(",combined,full,"))
            .count(),
        4
    );
    assert_eq!(
        lines
            .iter()
            .filter(|l| l.starts_with("mean,") && l.contains(",combined,full,"))
            .count(),
        2
    );

    // Second invocation: every run is skipped; nothing is rewritten in the run directories.
    let best = out.join("runs/rgb/seed0").join(BEST_CKPT);
    let eval = out.join("runs/late-sam/seed1").join(RUN_EVAL_FILE);
    let (t_best, t_eval) = (mtime(&best), mtime(&eval));
    let r2 = run_ablation(&o, &hidden()).unwrap();
    assert_eq!(
        (r2.skipped, r2.trained, r2.resumed, r2.evaluated),
        (4, 0, 0, 0)
    );
    assert!(r2.status.iter().all(|s| *s == RunStatus::Skipped));
    assert_eq!((mtime(&best), mtime(&eval)), (t_best, t_eval));
    // Same numbers, read back from the runs' eval.json (JSON text: equal to a few ulps).
    assert_eq!(r2.summary.len(), r.summary.len());
    for (a, b) in r2.summary.iter().zip(&r.summary) {
        assert_eq!(
            (&a.variant, &a.condition, &a.region, a.n),
            (&b.variant, &b.condition, &b.region, b.n)
        );
        let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * x.abs().max(1.0);
        for (x, y) in [
            (a.rmse, b.rmse),
            (a.delta1, b.delta1),
            (a.abs_rel, b.abs_rel),
            (a.mae, b.mae),
        ] {
            match (x, y) {
                (Some(x), Some(y)) => {
                    assert!(close(x.mean, y.mean) && close(x.std.unwrap(), y.std.unwrap()))
                }
                (None, None) => {}
                _ => panic!("{a:?} vs {b:?}"),
            }
        }
    }

    // A trained run without its eval.json is evaluated again, not retrained, and the same
    // checkpoint gives the same test numbers.
    let best_ls1 = out.join("runs/late-sam/seed1").join(BEST_CKPT);
    let t_ls1 = mtime(&best_ls1);
    std::fs::remove_file(&eval).unwrap();
    let r3 = run_ablation(&o, &hidden()).unwrap();
    assert_eq!((r3.skipped, r3.evaluated, r3.trained), (3, 1, 0));
    assert_eq!(mtime(&best_ls1), t_ls1, "not retrained");
    assert!(eval.is_file());
    let rm = |r: &AblationResult| {
        r.runs
            .iter()
            .find(|x| x.variant == "late-sam" && x.seed == 1)
            .unwrap()
            .headline()
            .unwrap()
            .rmse
    };
    assert!(
        (rm(&r3) - rm(&r)).abs() <= 1e-9,
        "{} vs {}",
        rm(&r3),
        rm(&r)
    );

    // An interrupted run continues from its last checkpoint (exact resume: the same test
    // numbers as the uninterrupted run).
    let out2 = tmp.path().join("abl2");
    let mut o2 = o.clone();
    o2.out = out2.clone();
    o2.variants = vec![Variant::Rgb];
    o2.seeds = vec![0];
    let model = variant_models(&o2).unwrap().remove(0).1;
    let partial = train(
        &{
            let mut t = o2.run.train_options(out2.join("runs/rgb/seed0"), &model, 0);
            t.checkpointing.stop_after = Some(1);
            t
        },
        &Progress::hidden(),
    )
    .unwrap();
    assert!(partial.interrupted);
    let r4 = run_ablation(&o2, &hidden()).unwrap();
    assert_eq!((r4.resumed, r4.trained), (1, 0));
    let rgb0 = |r: &AblationResult| {
        r.runs
            .iter()
            .find(|x| x.variant == "rgb" && x.seed == 0)
            .unwrap()
            .headline()
            .unwrap()
            .rmse
    };
    assert!(
        (rgb0(&r4) - rgb0(&r)).abs() <= 1e-9,
        "{} vs {}",
        rgb0(&r4),
        rgb0(&r)
    );

    // Other options in the same directory are refused rather than mixed.
    let mut other = o.clone();
    other.run.schedule.lr = 1e-2;
    let err = run_ablation(&other, &hidden()).unwrap_err().to_string();
    assert!(err.contains("other training options"), "{err}");
    assert!(err.contains("(lr: 0.002 there, 0.01 asked)"), "{err}");
}

#[test]
fn stat_matches_a_hand_computed_sample_std() {
    let _torch = crate::torch_lock();
    let s = Stat::of(&[4.0, 5.0, 9.0]).unwrap();
    assert!((s.mean - 6.0).abs() < 1e-12);
    // ((−2)² + (−1)² + 3²) / (3 − 1) = 7.
    assert!((s.std.unwrap() - 7f64.sqrt()).abs() < 1e-12);
}

#[test]
fn bar_chart_and_picture_row() {
    let _torch = crate::torch_lock();
    let png = bar_chart_png(
        "test RMSE",
        &["rgb", "late-sam"],
        &[5.0, 4.0],
        &[0.5, f64::NAN],
        "RMSE (m)",
    )
    .unwrap();
    let img = image::load_from_memory(&png).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (500, 420));
    let coloured = img
        .pixels()
        .filter(|p| p.0[0] != p.0[1] || p.0[1] != p.0[2])
        .count();
    assert!(coloured > 5000, "bars drawn: {coloured} coloured pixels");

    // Five 800x350 panels: two rows of three cells, one shared colour bar.
    let max_m = 80.0;
    let depth: Vec<f32> = (0..800 * 350)
        .map(|i| 1.0 + (i % 800) as f32 / 10.0)
        .collect();
    let panel = colorize_depth(&depth, 800, 350, max_m);
    let names = ["image", "radar", "GT", "RGB only", "fusion"];
    let panels: Vec<(&str, image::RgbImage)> = names.iter().map(|n| (*n, panel.clone())).collect();
    let img = image::load_from_memory(&picture_row_png(&panels, max_m).unwrap())
        .unwrap()
        .to_rgb8();
    let (w, h) = img.dimensions();
    assert_eq!(w, 3 * 800 + 4 * 8);
    assert!(h > 2 * 350 && h < 2 * 350 + 200, "height {h}");
    // The colour bar: a row below the panels running from the colour of ~0 m (left) to the
    // colour of ~max_m (right) of colorize_depth.
    let bw = w - 2 * 8 - 800 / 4;
    let x0 = 8 + 800 / 8;
    let near = colorize_depth(&[0.5 / bw as f32 * max_m], 1, 1, max_m);
    let far = colorize_depth(&[(bw as f32 - 0.5) / bw as f32 * max_m], 1, 1, max_m);
    let found = (2 * 350..h).any(|y| {
        img.get_pixel(x0, y) == near.get_pixel(0, 0)
            && img.get_pixel(x0 + bw - 1, y) == far.get_pixel(0, 0)
    });
    assert!(found, "no colour bar with the colorize_depth colours");
    assert!(picture_row_png(&[], max_m).is_err());
}
