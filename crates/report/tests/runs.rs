//! `report` shows training runs (settings, every validation, curves.png), exported models (not
//! "skipped") and one table comparing every model found.

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

    let models = &s.sections[0].doc.to_markdown();
    assert!(
        models.contains("| fusion | `") && models.contains("test, cap 80 m | 8 | 9.750 |"),
        "{models}"
    );
    assert!(
        models.contains("validation, best epoch (1) | 4 | 9.500 |"),
        "{models}"
    );

    let train = &s.sections[2];
    assert_eq!(train.images.len(), 1, "curves.png");
    let train_md = train.doc.to_markdown();
    assert!(train_md.contains("`tiny` (late fusion + attention), 2 epochs of batch 4"));
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
