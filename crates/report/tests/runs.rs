//! `report` shows training runs (command, settings, every validation, curves.png, the
//! "unfinished" mark), exported models (not "skipped") and the comparison of every model found:
//! the test rows in one table (best of each metric in bold, one-seed differences said so), the
//! validation rows in another.

use std::path::Path;

use depthsense_report::{render, Kind, ReportOptions};
use serde_json::json;

fn write(p: &Path, bytes: &[u8]) {
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, bytes).unwrap();
}

fn val(epoch: u64, it: u64, rmse: f64) -> serde_json::Value {
    json!({"epoch": epoch, "iteration": it, "rmse": rmse, "mae": rmse / 2.0,
           "abs_rel": 0.3, "delta1": 0.5, "n_images": 4, "n_pixels": 900})
}

#[test]
fn training_runs_exports_and_the_model_comparison() {
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    // A training run of two epochs.
    let run = runs.join("fusion");
    write(
        &run.join("config.json"),
        json!({"train": {"data": "runs/prepared", "out": "runs/fusion", "epochs": 2,
                          "batch_size": 4, "lr": 0.002, "seed": 7},
               "model": {"name": "tiny", "fusion": "late", "attention": true},
               "partition": {"train_samples": 64, "val_samples_used": 16}})
        .to_string()
        .as_bytes(),
    );
    let lines = [
        json!({"kind": "val", "epoch": 0, "iteration": 0, "val": val(0, 0, 14.0)}),
        json!({"kind": "iter", "epoch": 0, "iteration": 1, "loss": 50.0, "lr": 0.002}),
        json!({"kind": "epoch", "epoch": 1, "iteration": 16, "val": val(1, 16, 9.5)}),
        json!({"kind": "epoch", "epoch": 2, "iteration": 32, "val": val(2, 32, 10.0)}),
    ];
    let jsonl: String = lines.iter().map(|l| format!("{l}\n")).collect();
    write(&run.join("metrics.jsonl"), jsonl.as_bytes());
    let loss = [(1u64, 50.0), (32, 20.0)];
    let v = [(0u64, 14.0), (16, 9.5), (32, 10.0)];
    let png = depthsense_viz::plot::curves_png(&[("train loss", &loss)], &[("val", &v)]).unwrap();
    write(&run.join("curves.png"), &png);
    write(&run.join("best.safetensors"), b"weights");
    // Its evaluation on the test scenes.
    let row = |cap: f64, rmse: f64| {
        json!({"condition": "combined", "region": "full", "cap_m": cap, "n_images": 8,
               "n_pixels": 9000, "metrics": {"rmse": rmse, "mae": 4.0, "abs_rel": 0.25,
               "delta1": 0.6}})
    };
    write(
        &runs.join("eval-fusion/tables.json"),
        json!({"models": [{"name": "fusion", "report": {"rows": [row(50.0, 7.0), row(80.0, 9.75)]}}]})
            .to_string()
            .as_bytes(),
    );
    // An exported model beside the run folder.
    write(&runs.join("fusion.onnx"), b"onnx bytes");
    write(
        &runs.join("fusion.onnx.json"),
        json!({"format_version": "depthsense-export-v1", "format": "onnx", "precision": "fp32",
               "batch": "dynamic", "preset": "tiny", "checkpoint": "runs/fusion/best.safetensors",
               "checkpoint_sha256": "0123456789abcdef",
               "inputs": [{"name": "image", "shape": ["N", 3, 350, 800]}],
               "output": {"name": "depth", "shape": ["N", 1, 350, 800]},
               "trained_radar": {"radar_sweeps": 5, "radar_filters": true,
                                 "radar_velocity_compensation": false,
                                 "radar_channels": ["RADAR_FRONT"]}})
        .to_string()
        .as_bytes(),
    );

    let (s, _) = render(&ReportOptions {
        runs: vec![runs.clone()],
        out: tmp.path().join("page"),
        ..ReportOptions::default()
    })
    .unwrap();
    let kinds: Vec<Kind> = s.sections.iter().map(|x| x.kind).collect();
    assert_eq!(kinds, [Kind::Models, Kind::Eval, Kind::Train, Kind::Export]);
    assert!(s.skipped.is_empty(), "{:?}", s.skipped);

    let (test, val) = split_models(&s.sections[0].doc.to_markdown());
    assert!(
        test.contains("| fusion | eval | `") && test.contains("| 80 | 1 | 8 | 9.750 |"),
        "{test}"
    );
    assert!(
        !test.contains("best epoch"),
        "no validation row in the test table: {test}"
    );
    assert!(
        val.contains("| best epoch (1) | finished | 4 | 9.500 |"),
        "{val}"
    );
    assert!(
        !val.contains("9.750"),
        "no test row among the validations: {val}"
    );

    let train = &s.sections[2];
    assert_eq!(train.images.len(), 1, "curves.png");
    let train_md = train.doc.to_markdown();
    assert!(train_md.contains("`tiny` (late fusion + attention), 2 epochs of batch 4"));
    assert!(!train_md.contains("unfinished"), "{train_md}");
    assert!(train_md.contains("| 2 | 32 | 10.000 | 5.000 | 0.300 | 0.500 | 4 |"));

    let export = &s.sections[3].doc.to_markdown();
    assert!(
        export.contains("`fusion.onnx`: onnx (fp32, batch dynamic)"),
        "{export}"
    );
    assert!(
        export.contains("5 sweep(s) per channel (RADAR_FRONT)"),
        "{export}"
    );
}

/// An output whose JSON records its document is rendered from that document (its `.md` beside
/// it is not read back), every text escaped by the page's template; one written before
/// documents were recorded shows its `.md`.
#[test]
fn a_recorded_document_is_rendered_from_the_json() {
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    let mut t = depthsense_metrics::table::MdTable::new(&[
        ("preset", depthsense_metrics::table::Align::Left),
        ("ms", depthsense_metrics::table::Align::Right),
    ]);
    t.row(&["<script>x</script>", "12"]);
    let mut doc = depthsense_metrics::doc::Doc::new();
    doc.heading(1, "Cost")
        .table(t)
        .command(Some("depthsense experiment cost"));
    write(
        &runs.join("new/cost.json"),
        json!({"rows": [], "document": doc}).to_string().as_bytes(),
    );
    write(&runs.join("new/cost.md"), b"# Not this one\n");
    write(
        &runs.join("old/cost.json"),
        json!({"rows": []}).to_string().as_bytes(),
    );
    write(&runs.join("old/cost.md"), b"# Old\n\n| a |\n|---|\n| 1 |\n");
    let out = tmp.path().join("page");
    let (s, html) = render(&ReportOptions {
        runs: vec![runs],
        out,
        ..ReportOptions::default()
    })
    .unwrap();
    let new = s
        .sections
        .iter()
        .find(|x| x.source_dir.ends_with("new"))
        .unwrap();
    assert_eq!(new.doc, doc);
    let old = s
        .sections
        .iter()
        .find(|x| x.source_dir.ends_with("old"))
        .unwrap();
    assert_eq!(old.doc.to_markdown(), "# Old\n\n| a |\n|---|\n| 1 |\n");
    assert!(html.contains("<td>&lt;script&gt;x&lt;/script&gt;</td><td class=\"r\">12</td>"));
    assert!(!html.contains("<script>") && !html.contains("Not this one"));
    assert!(
        html.contains("<h3>Old</h3>"),
        "the old output's Markdown, headings shifted"
    );
}

/// The comparison's Markdown cut at its validation heading: (test part, validation part).
fn split_models(md: &str) -> (String, String) {
    assert!(md.starts_with("# Test scenes\n"), "{md}");
    match md.split_once("# Validation") {
        Some((t, v)) => (t.to_string(), v.to_string()),
        None => (md.to_string(), String::new()),
    }
}

/// `tables.json` of an evaluation of `models` (name, RMSE, δ1) on `data`, `images` test images.
fn eval_tables(dir: &Path, data: &str, images: u64, models: &[(&str, f64, f64)]) {
    let models: Vec<serde_json::Value> = models
        .iter()
        .map(|(name, rmse, d1)| {
            json!({"name": name, "report": {"rows": [
                {"condition": "combined", "region": "full", "cap_m": 80.0, "n_images": images,
                 "n_pixels": 9000, "metrics": {"rmse": rmse, "mae": rmse / 2.0, "abs_rel": 0.25,
                 "delta1": d1}}]}})
        })
        .collect();
    let cmd = format!("depthsense eval --checkpoint x/best.safetensors --data {data}");
    write(
        &dir.join("tables.json"),
        json!({"models": models, "command_line": cmd})
            .to_string()
            .as_bytes(),
    );
}

/// A training run in `dir`: `epochs` in config.json, validations after `done` epochs, and the
/// recorded command when given.
fn run_folder(dir: &Path, epochs: u64, done: u64, command: Option<serde_json::Value>) {
    let mut cfg = json!({"train": {"data": "runs/prepared", "out": dir, "epochs": epochs,
                          "batch_size": 4, "lr": 0.002, "seed": 7},
               "model": {"name": "tiny", "fusion": "late", "attention": false},
               "partition": {"train_samples": 64, "val_samples_used": 16}});
    if let Some(c) = command {
        cfg["command"] = c;
    }
    write(&dir.join("config.json"), cfg.to_string().as_bytes());
    let mut lines =
        vec![json!({"kind": "val", "epoch": 0, "iteration": 0, "val": val(0, 0, 14.0)})];
    for e in 1..=done {
        lines.push(json!({"kind": "iter", "epoch": e - 1, "iteration": 8 * e, "loss": 9.0}));
        lines.push(
            json!({"kind": "epoch", "epoch": e, "iteration": 8 * e, "val": val(e, 8 * e, 12.0 - e as f64)}),
        );
    }
    // An interrupted run logged iterations of the epoch it did not finish.
    lines.push(json!({"kind": "iter", "epoch": done, "iteration": 8 * done + 3, "loss": 8.0}));
    let jsonl: String = lines.iter().map(|l| format!("{l}\n")).collect();
    write(&dir.join("metrics.jsonl"), jsonl.as_bytes());
}

fn page(runs: &Path, out: &Path) -> (depthsense_report::ReportSummary, String) {
    render(&ReportOptions {
        runs: vec![runs.to_path_buf()],
        out: out.to_path_buf(),
        ..ReportOptions::default()
    })
    .unwrap()
}

/// The test table marks the best value of each metric (lower RMSE / MAE / AbsRel, higher δ1)
/// among the rows of one test set only, and says that a difference between models of one seed
/// each is one seed; an experiment's arms (mean over seeds) come in as rows without that
/// caveat.
#[test]
fn the_best_of_each_test_set_is_bold_and_one_seed_is_said() {
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    // Two checkpoints on one test set: `fusion` has the lower RMSE, `rgb` the higher δ1.
    eval_tables(&runs.join("eval-a"), "runs/p", 30, &[("rgb", 9.5, 0.71)]);
    eval_tables(
        &runs.join("eval-b"),
        "runs/p",
        30,
        &[("fusion", 9.25, 0.70)],
    );
    // Another test set (other data): never compared with those two.
    eval_tables(
        &runs.join("eval-c"),
        "runs/other",
        30,
        &[("elsewhere", 1.0, 0.99)],
    );
    let (s, html) = page(&runs, &tmp.path().join("page"));
    let (test, val) = split_models(&s.sections[0].doc.to_markdown());
    assert!(
        val.is_empty(),
        "no training run, no validation table: {val}"
    );
    assert!(
        test.contains("| rgb | eval | ")
            && test.contains("| 9.500 | 4.750 | **0.250** | **0.710** |"),
        "{test}"
    );
    assert!(
        test.contains("| **9.250** | **4.625** | **0.250** | 0.700 |"),
        "{test}"
    );
    assert!(
        test.contains("| 1.000 | 0.500 | 0.250 | 0.990 |"),
        "a test set of one row marks nothing: {test}"
    );
    assert!(test.contains("one seed: not a finding"), "{test}");
    assert!(
        test.contains("`rgb`, `fusion` are one trained model each"),
        "{test}"
    );
    assert!(!test.contains("`elsewhere`"), "{test}");
    assert!(html.contains("<td class=\"r\"><strong>9.250</strong></td>"));

    // An ablation's arms: mean over 3 seeds on one test set, the best marked, no one-seed words.
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    let stat = |m: f64| json!({"mean": m, "std": 0.1, "n": 3});
    let summary = |variant: &str, cap: f64, rmse: f64| {
        json!({"variant": variant, "condition": "combined", "region": "full", "cap_m": cap,
               "n": 3, "rmse": stat(rmse), "mae": stat(rmse / 2.0), "abs_rel": stat(0.2),
               "delta1": stat(0.7)})
    };
    let run = json!({"rows": [{"condition": "combined", "region": "full", "n_images": 40}]});
    write(
        &runs.join("abl/ablation.json"),
        json!({"options": {"data": "runs/p", "command_line": "depthsense experiment ablation"},
               "runs": [run, run],
               "summary": [summary("rgb", 50.0, 7.0), summary("rgb", 80.0, 9.0),
                           summary("late-sam", 80.0, 8.5),
                           {"variant": "rgb", "condition": "day", "region": "full", "cap_m": 80.0}]})
        .to_string()
        .as_bytes(),
    );
    let (s, _) = page(&runs, &tmp.path().join("page"));
    assert_eq!(s.sections[0].kind, Kind::Models);
    let (test, _) = split_models(&s.sections[0].doc.to_markdown());
    assert!(
        test.contains("| rgb | ablation | `") && test.contains("| 80 | 3 | 40 | 9.000 | 4.500 |"),
        "the largest cap of each arm: {test}"
    );
    assert!(
        test.contains("| late-sam | ablation | `") && test.contains("| **8.500** | **4.250** |"),
        "{test}"
    );
    assert!(!test.contains("one seed"), "{test}");
}

/// A run that stopped before its last epoch is marked unfinished in its section and in the
/// validation table; the command config.json records is the section's command (quoted where a
/// shell would need it); a run without one says it was not recorded.
#[test]
fn unfinished_runs_are_marked_and_the_command_is_shown() {
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    let argv = json!([
        "depthsense",
        "train",
        "--data",
        "runs/my data",
        "--epochs",
        "3",
        "--out",
        "runs/cut"
    ]);
    run_folder(&runs.join("cut"), 3, 1, Some(argv));
    run_folder(&runs.join("done"), 2, 2, None);
    let (s, html) = page(&runs, &tmp.path().join("page"));
    let section = |name: &str| {
        s.sections
            .iter()
            .find(|x| x.kind == Kind::Train && x.source_dir.ends_with(name))
            .unwrap()
    };
    let cut = section("cut");
    assert_eq!(
        cut.command_line.as_deref(),
        Some("depthsense train --data 'runs/my data' --epochs 3 --out runs/cut")
    );
    assert!(
        html.contains("<pre>depthsense train --data &#39;runs/my data&#39; --epochs 3")
            || html.contains("<pre>depthsense train --data 'runs/my data' --epochs 3"),
        "{html}"
    );
    let cut_md = cut.doc.to_markdown();
    assert!(
        cut_md.contains(
            "`tiny` (late fusion), **unfinished (epoch 1 of 3; continue with --resume)**, batch 4"
        ),
        "{cut_md}"
    );
    let done = section("done");
    assert_eq!(done.command_line, None);
    assert!(done.doc.to_markdown().contains("2 epochs of batch 4"));
    assert!(html.contains("not recorded in its config.json"));

    let (test, val) = split_models(&s.sections[0].doc.to_markdown());
    assert!(
        test.contains("No model was scored on test scenes"),
        "{test}"
    );
    assert!(
        val.contains("| best epoch (1) | **unfinished (epoch 1 of 3; continue with --resume)** |"),
        "{val}"
    );
    assert!(val.contains("| best epoch (2) | finished |"), "{val}");
}

/// The demo's section brings its two models' test rows (its `tables.json`) into the test table
/// and its two runs' best validations into the validation table.
#[test]
fn the_demo_models_are_compared() {
    let tmp = tempfile::tempdir().unwrap();
    let demo = tmp.path().join("runs/demo");
    let report = demo.join("report");
    write(
        &report.join("summary.json"),
        json!({"summary": {}, "plan": {}, "command_line": "depthsense demo",
               "document": {"blocks": []}})
        .to_string()
        .as_bytes(),
    );
    eval_tables(
        &report,
        "unused",
        30,
        &[("rgb", 9.0, 0.7), ("fusion", 8.75, 0.72)],
    );
    run_folder(&demo.join("rgb"), 2, 2, None);
    run_folder(&demo.join("fusion"), 2, 2, None);
    let (s, _) = page(&tmp.path().join("runs"), &tmp.path().join("page"));
    let kinds: Vec<Kind> = s.sections.iter().map(|x| x.kind).collect();
    assert_eq!(kinds, [Kind::Models, Kind::Demo]);
    let (test, val) = split_models(&s.sections[0].doc.to_markdown());
    let prepared = format!("`{}`", demo.join("prepared").display());
    assert!(
        test.contains(&format!(
            "| rgb | demo | `{}` | {prepared} | 80 | 1 | 30 | 9.000 |",
            report.display()
        )),
        "{test}"
    );
    assert!(
        test.contains("| fusion | demo | ") && test.contains("| **8.750** |"),
        "{test}"
    );
    assert!(test.contains("one seed: not a finding"), "{test}");
    assert_eq!(
        val.matches("| best epoch (2) | finished |").count(),
        2,
        "{val}"
    );
}

/// Run folders written before records were typed (no `format_version`, the literals above)
/// render as before; a record that lacks a field the report shows is skipped with its file and
/// the field, and no value is shown as "null".
#[test]
fn an_incomplete_record_is_skipped_with_its_file_and_field() {
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    run_folder(&runs.join("old"), 3, 3, None);
    run_folder(&runs.join("broken"), 3, 3, None);
    let cfg = runs.join("broken/config.json");
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&cfg).unwrap()).unwrap();
    v["train"].as_object_mut().unwrap().remove("batch_size");
    write(&cfg, v.to_string().as_bytes());
    let log = runs.join("old-log");
    run_folder(&log, 3, 3, None);
    let mut text = std::fs::read_to_string(log.join("metrics.jsonl")).unwrap();
    text = text.replacen("\"rmse\":", "\"rmse_m\":", 1);
    write(&log.join("metrics.jsonl"), text.as_bytes());

    let (s, html) = page(&runs, &tmp.path().join("page"));
    let trains: Vec<_> = s
        .sections
        .iter()
        .filter(|x| x.kind == Kind::Train)
        .collect();
    assert_eq!(trains.len(), 1, "only the readable run");
    let md = trains[0].doc.to_markdown();
    assert!(
        md.contains("`tiny` (late fusion), 3 epochs of batch 4, lr 0.002, seed 7, on `runs/prepared` (64 training / 16 validation samples used)."),
        "{md}"
    );
    assert!(
        md.contains("| 3 | 24 | 9.000 | 4.500 | 0.300 | 0.500 | 4 |"),
        "{md}"
    );
    let reasons: Vec<(String, String)> = s
        .skipped
        .iter()
        .map(|k| (k.path.display().to_string(), k.reason.clone()))
        .collect();
    assert!(
        reasons.contains(&(
            cfg.display().to_string(),
            "field \"train.batch_size\": missing".into()
        )),
        "{reasons:?}"
    );
    assert!(
        reasons.contains(&(
            log.join("metrics.jsonl").display().to_string(),
            "line 1: field \"val.rmse\": missing".into()
        )),
        "{reasons:?}"
    );
    assert!(!html.contains("null") && !md.contains("null"));
}
