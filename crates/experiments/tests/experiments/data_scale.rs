//! `experiment data-scale` on a small setting (2 sizes, 1 seed, a few iterations): every run
//! trains the same iterations on its nested subset, the JSON, tables and plot are written, and
//! a second invocation reads every run back.

use crate::common;

use depthsense_dataset::outputs::{CONFIG_FILE, METRICS_FILE};
use depthsense_experiments::data_scale::{
    run_data_scale, schedule, DataScaleOptions, CSV_FILE, JSON_FILE, MD_FILE, PNG_FILE,
};
use depthsense_train::metrics_log::{read_log, BadLine};

use common::{hidden, mtime, quick_runs};

#[test]
fn data_scale_trains_matched_iterations_and_writes_json_and_plot() {
    let _torch = crate::torch_lock();
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    depthsense_data::write_toy_dataset(&data, 10, 2, 64, 32, 2).unwrap();
    let out = tmp.path().join("ds");
    let mut run = quick_runs(&data);
    run.schedule.epochs = 2;
    let opts = DataScaleOptions {
        run,
        out: out.clone(),
        sizes: vec![4, 8],
        arms: vec!["rgb".parse().unwrap(), "late-sam".parse().unwrap()],
        at_largest: vec!["late-sam+radar-skip=4".parse().unwrap()],
        seeds: vec![0],
        iterations: None,
        eval: Default::default(),
        command_line: Some("test".into()),
    };
    // 8 images at batch 2: 4 iterations, 2 per validation.
    assert_eq!(schedule(&opts), (4, 2));
    let r = run_data_scale(&opts, &hidden()).unwrap();
    for f in [MD_FILE, CSV_FILE, JSON_FILE, PNG_FILE] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let png = image::open(out.join(PNG_FILE)).unwrap();
    assert_eq!(png.width(), 1040, "two panels of 520 px");
    assert_eq!(r.runs.len(), 5, "2 sizes × 2 arms + 1 arm at the largest");
    for rec in &r.runs {
        let n = rec.train_options.loading.train_subset.unwrap();
        let cfg: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(rec.run_dir.join(CONFIG_FILE)).unwrap())
                .unwrap();
        assert_eq!(cfg["partition"]["train_samples"].as_u64(), Some(n as u64));
        let log = read_log(&rec.run_dir.join(METRICS_FILE), BadLine::Fail).unwrap();
        assert_eq!(log.epoch_ends.last().unwrap().epoch, Some(2));
        let at: Vec<(u64, u64)> = log.val.iter().map(|v| (v.epoch, v.iteration)).collect();
        assert_eq!(
            at.last(),
            Some(&(2, 4)),
            "validated every 2 iterations: {at:?}"
        );
        assert!(rec
            .run_dir
            .starts_with(out.join("runs").join(format!("n{n}"))));
    }
    // rows: the baseline has no margin; the others a margin equal to baseline − arm per seed
    let base = r.row(8, "rgb").unwrap();
    assert!(base.margin_m.is_none() && base.vs_baseline.is_none());
    for arm in ["late-sam", "late-sam+radar-skip=4"] {
        let row = r.row(8, arm).unwrap();
        let m = row.margin_m.unwrap().mean;
        assert!((m - (base.rmse.unwrap().mean - row.rmse.unwrap().mean)).abs() < 1e-9);
        assert!((row.passes - 1.0).abs() < 1e-12, "4 iterations × 2 / 8");
    }
    assert!(
        r.row(4, "late-sam+radar-skip=4").is_none(),
        "extra arms: largest N only"
    );
    assert!((r.row(4, "rgb").unwrap().passes - 2.0).abs() < 1e-12);
    assert!(
        r.trend.as_deref().unwrap().contains("no verdict"),
        "{:?}",
        r.trend
    );
    let md = std::fs::read_to_string(out.join(MD_FILE)).unwrap();
    assert!(
        md.contains("same **4 iterations**") && md.contains("| late-sam |"),
        "{md}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join(JSON_FILE)).unwrap()).unwrap();
    assert_eq!(json["iterations"], 4);
    assert_eq!(json["rows"].as_array().unwrap().len(), 5);
    // second invocation: every run read back from its eval.json
    let eval_json = r.runs[0].run_dir.join("eval.json");
    let before = mtime(&eval_json);
    let again = run_data_scale(&opts, &hidden()).unwrap();
    assert_eq!(mtime(&eval_json), before);
    assert_eq!(again.rows, r.rows);
    // runs trained by another process into another --out (`--seed-list`), moved into this
    // one, are read back too, with their new folders
    let moved = tmp.path().join("moved");
    std::fs::create_dir_all(&moved).unwrap();
    std::fs::rename(out.join("runs"), moved.join("runs")).unwrap();
    let there = run_data_scale(
        &DataScaleOptions {
            out: moved.clone(),
            ..opts.clone()
        },
        &hidden(),
    )
    .unwrap();
    assert_eq!(there.rows, r.rows);
    for rec in &there.runs {
        assert!(rec.run_dir.starts_with(&moved), "{}", rec.run_dir.display());
        assert!(rec.train_options.out.starts_with(&moved));
    }
    assert_eq!(
        mtime(&moved.join("runs/n4/rgb/seed0/eval.json")),
        before,
        "nothing retrained"
    );
    std::fs::rename(moved.join("runs"), out.join("runs")).unwrap();
    // the report finds it: one section with its table and plot, not one per run
    let rep = tmp.path().join("report");
    let s = depthsense_report::build_report(&depthsense_report::ReportOptions {
        runs: vec![out.clone()],
        out: rep.clone(),
        ..Default::default()
    })
    .unwrap();
    let kinds: Vec<_> = s.sections.iter().map(|x| x.kind).collect();
    assert!(
        kinds.contains(&depthsense_report::Kind::DataScale),
        "{kinds:?}"
    );
    assert!(
        !kinds.contains(&depthsense_report::Kind::Train),
        "{kinds:?}"
    );
    let html = std::fs::read_to_string(rep.join("report.html")).unwrap();
    assert!(html.contains("Radar&#39;s margin") || html.contains("Radar's margin"));
    // a size larger than the training set is refused before anything is trained
    let too_big = DataScaleOptions {
        sizes: vec![4, 1000],
        out: tmp.path().join("big"),
        ..opts
    };
    let e = run_data_scale(&too_big, &hidden()).unwrap_err().to_string();
    assert!(e.contains("size 1000") && e.contains("--sizes"), "{e}");
    assert!(!tmp.path().join("big").exists());
}
