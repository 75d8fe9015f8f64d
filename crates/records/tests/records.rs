//! The records read today's files and the ones written before they carried a version (literal
//! JSON of both, as the commands wrote them), write back the same JSON, and name the file and
//! the field of a record they cannot read.

use std::path::Path;

use depthsense_records::metrics_log::{
    self, BadLine, EpochRecord, IterRecord, MetricsRecord, PdaValRecord, ValLine, ValRecord,
    METRICS_VERSION,
};
use depthsense_records::run_config::{Command, RunConfig, RUN_CONFIG_VERSION};
use depthsense_records::sidecar::SidecarRecord;
use depthsense_records::tables::{TablesRecord, TABLES_VERSION};
use depthsense_records::{checked, read_json, to_json_line, RecordError, LEGACY_VERSION};
use serde_json::{json, Value};

/// A config.json as `train` wrote it before records were typed (no `format_version`).
fn old_train_config() -> Value {
    json!({
        "command": ["depthsense", "train", "--data", "p", "--out", "runs/a"],
        "device": "cpu",
        "init_from": {"file": "x.pth", "loaded": 10, "new": ["head.w"],
                      "partly_loaded": [], "unused_file_tensors": 2},
        "model": {"name": "tiny", "fusion": "late", "attention": false, "backbone_depth": 18,
                  "sid": {"alpha": 1.0, "beta": 80.0, "k": 80}},
        "partition": {"method": "every 5th scene", "train_samples": 64, "val_samples": 16,
                      "val_samples_used": 8, "val_scenes": ["scene-0001"]},
        "schedule": [{"start_iteration": 0, "end_iteration": 10, "lr": 0.001},
                     {"start_iteration": 10, "end_iteration": 30, "lr": 0.0005, "warmup": 2}],
        "train": {"data": "p", "out": "runs/a", "epochs": 3, "batch_size": 4, "lr": 0.001,
                  "seed": 7, "momentum": 0.9, "eval": {"caps_m": [50.0, 80.0]}}
    })
}

#[test]
fn a_config_of_before_reads_as_version_1_and_writes_back_the_same_json() {
    let v = old_train_config();
    let RunConfig::Train(c) = RunConfig::from_value(v.clone(), Path::new("c.json")).unwrap() else {
        panic!("a train config")
    };
    assert_eq!(c.format_version, LEGACY_VERSION);
    assert_eq!(
        (c.train.epochs, c.train.batch_size, c.train.seed),
        (3, 4, 7)
    );
    assert_eq!(c.model.fusion_words(), "late fusion");
    assert_eq!(c.partition.val_samples_used, 8);
    assert_eq!(c.schedule[1].warmup, 2);
    assert_eq!(c.init_from.as_ref().unwrap().new, ["head.w"]);
    assert_eq!(
        c.command.as_ref().and_then(Command::shell_line).as_deref(),
        Some("depthsense train --data p --out runs/a")
    );
    // Written today: the same JSON plus its version.
    let mut today = c.clone();
    today.format_version = RUN_CONFIG_VERSION;
    let mut expected = v;
    expected["format_version"] = json!(RUN_CONFIG_VERSION);
    assert_eq!(serde_json::to_value(&*today).unwrap(), expected);
    let back = RunConfig::from_value(expected, Path::new("c.json")).unwrap();
    assert_eq!(back, RunConfig::Train(today));
}

#[test]
fn a_mer_config_is_told_by_its_mer_train_options() {
    let v = json!({"mer_train": {"data": "p", "out": "r", "epochs": 2, "batch_size": 4,
                                 "lr": 0.01, "seed": 0, "augment": true},
                   "pda": {"window": 3}, "parameters": 1234, "device": "cpu",
                   "partition": {"train_samples": 4, "val_samples_used": 2}});
    let c = RunConfig::from_value(v.clone(), Path::new("c.json")).unwrap();
    assert!(matches!(c, RunConfig::Mer(_)));
    assert_eq!((c.options().epochs, c.options().lr), (2, 0.01));
    let RunConfig::Mer(m) = c else { unreachable!() };
    assert_eq!(serde_json::to_value(&*m).unwrap()["augment"], Value::Null);
    assert_eq!(
        serde_json::to_value(&*m).unwrap()["mer_train"]["augment"],
        json!(true)
    );
}

/// An incomplete or mistyped record names its file and its field; a newer version is refused.
#[test]
fn an_incomplete_record_names_its_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("config.json");
    let mut v = old_train_config();
    v["train"].as_object_mut().unwrap().remove("epochs");
    std::fs::write(&p, v.to_string()).unwrap();
    let e = RunConfig::read(&p).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("train.epochs"));
    assert_eq!(
        e.to_string(),
        format!("{}: field \"train.epochs\": missing", p.display())
    );

    let mut v = old_train_config();
    v["partition"]["train_samples"] = json!("many");
    std::fs::write(&p, v.to_string()).unwrap();
    let e = RunConfig::read(&p).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("partition.train_samples"));
    assert!(e.problem.contains("invalid type"), "{e}");

    let mut v = old_train_config();
    v["format_version"] = json!(RUN_CONFIG_VERSION + 1);
    std::fs::write(&p, v.to_string()).unwrap();
    let e = RunConfig::read(&p).unwrap_err().to_string();
    assert!(
        e.contains("field \"format_version\"") && e.contains("newer"),
        "{e}"
    );

    std::fs::write(&p, "{").unwrap();
    let e = RunConfig::read(&p).unwrap_err();
    assert!(
        e.field.is_none() && e.problem.starts_with("not valid JSON"),
        "{e}"
    );

    // A line of metrics.jsonl: the file, the line and the field.
    let log = dir.path().join("metrics.jsonl");
    std::fs::write(
        &log,
        concat!(
            r#"{"kind":"iter","epoch":0,"iteration":1,"loss":2.0}"#,
            "\n",
            r#"{"kind":"epoch","epoch":1,"val":{"epoch":1,"iteration":1,"mae":1.0,"abs_rel":0.5,"delta1":0.25,"n_images":2,"n_pixels":9}}"#,
            "\n"
        ),
    )
    .unwrap();
    let e: RecordError = metrics_log::read::<ValRecord>(&log, BadLine::Fail).unwrap_err();
    assert_eq!((e.line, e.field.as_deref()), (Some(2), Some("val.rmse")));
    assert_eq!(
        e.to_string(),
        format!("{} line 2: field \"val.rmse\": missing", log.display())
    );
}

#[test]
fn metrics_lines_of_before_and_of_today_read_and_round_trip() {
    // Written before records were typed: no versions, an iter without lr, an epoch line
    // without timings, one without val, a NaN written as null, a kind unknown here.
    let old = concat!(
        r#"{"epoch":0,"iteration":0,"kind":"val","val":{"abs_rel":0.3,"delta1":0.5,"epoch":0,"iteration":0,"mae":7.0,"n_images":4,"n_pixels":900,"rmse":14.0}}"#,
        "\n",
        r#"{"epoch":0,"iteration":1,"kind":"iter","loss":50.0}"#,
        "\n",
        r#"{"epoch":1,"iteration":16,"kind":"epoch","lr":0.001,"seconds":3.5,"train_loss":20.0,"val":{"abs_rel":0.3,"delta1":null,"epoch":1,"iteration":16,"mae":4.75,"n_images":4,"n_pixels":900,"rmse":9.5}}"#,
        "\n",
        r#"{"epoch":2,"kind":"epoch","seconds":2.0}"#,
        "\n",
        r#"{"kind":"note","text":"from a newer writer"}"#,
        "\n",
        r#"{"kind":"iter","iteration":3,"lo"#,
    );
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("metrics.jsonl");
    std::fs::write(&p, old).unwrap();
    assert!(metrics_log::read::<ValRecord>(&p, BadLine::Fail).is_err());
    let recs = metrics_log::read::<ValRecord>(&p, BadLine::Skip).unwrap();
    assert_eq!(recs.len(), 5);
    let MetricsRecord::Iter(i) = &recs[1] else {
        panic!("{:?}", recs[1])
    };
    assert_eq!(
        (i.format_version, i.loss, i.lr),
        (LEGACY_VERSION, 50.0, None)
    );
    let (epoch, it, v) = recs[2].validation().unwrap();
    assert_eq!((epoch, it, v.rmse, v.n_pixels), (1, Some(16), 9.5, 900));
    assert!(v.delta1.is_nan(), "null reads as NaN");
    assert_eq!(recs[3].validation(), None);
    assert_eq!(recs[4], MetricsRecord::Other);

    // Today's lines: each with its version, keys sorted, and read back equal.
    let val = ValRecord {
        epoch: 1,
        iteration: 16,
        rmse: 9.5,
        mae: 4.75,
        abs_rel: 0.3,
        delta1: 0.5,
        n_images: 4,
        n_pixels: 900,
    };
    let today = [
        MetricsRecord::Val(ValLine::new(0, 0, val.clone())),
        MetricsRecord::Iter(IterRecord::new(0, 1, 50.0, 0.001)),
        MetricsRecord::Epoch(EpochRecord {
            seconds: Some(3.5),
            ..EpochRecord::new(1, 16, 20.0, val.clone())
        }),
    ];
    let text: Vec<String> = today.iter().map(|r| to_json_line(r).unwrap()).collect();
    assert_eq!(
        text[1],
        format!(
            r#"{{"epoch":0,"format_version":{METRICS_VERSION},"iteration":1,"kind":"iter","loss":50.0,"lr":0.001}}"#
        )
    );
    std::fs::write(&p, text.join("\n")).unwrap();
    let back = metrics_log::read::<ValRecord>(&p, BadLine::Fail).unwrap();
    assert_eq!(back, today);
}

#[test]
fn pda_validations_are_told_apart_and_round_trip() {
    let v = PdaValRecord {
        epoch: 1,
        iteration: 8,
        loss: 0.6,
        precision: 0.5,
        recall: 0.25,
        auc: 0.75,
        pairs: 100,
        positives: 30,
    };
    let line =
        serde_json::to_value(MetricsRecord::Epoch(EpochRecord::new(1, 8, 0.7, v.clone()))).unwrap();
    assert!(metrics_log::holds_pda(&[(1, line.clone())]));
    let back: MetricsRecord<PdaValRecord> =
        metrics_log::parse_line(line, Path::new("m"), 1).unwrap();
    assert_eq!(back.validation().unwrap().2, &v);
}

/// tables.json of before (no version; a report without `config`, rows without every metric)
/// and of today.
#[test]
fn tables_of_before_and_of_today() {
    let row = |cap: f64, rmse: f64| {
        json!({"condition": "combined", "region": "full", "cap_m": cap, "n_images": 8,
               "n_pixels": 9000, "metrics": {"rmse": rmse, "mae": 4.0, "abs_rel": 0.25,
               "delta1": 0.6, "delta2": 0.8}})
    };
    let old = json!({"models": [{"name": "fusion", "report": {"rows": [row(50.0, 7.0), row(80.0, 9.75)],
                     "images_seen": 8}}], "command_line": null, "tables": {"main": []}});
    let t: TablesRecord = checked(old.clone(), Path::new("tables.json"), None).unwrap();
    assert_eq!(t.format_version, LEGACY_VERSION);
    let head = t.models[0].headline().unwrap();
    assert_eq!(
        (head.cap_m, head.metrics.rmse, head.n_images),
        (80.0, 9.75, 8)
    );
    let mut expected = old.clone();
    expected["format_version"] = json!(LEGACY_VERSION);
    assert_eq!(
        serde_json::to_value(&t).unwrap(),
        expected,
        "the same JSON back"
    );

    // Today's, from a metrics::Report.
    let mut ev =
        depthsense_metrics::Evaluator::new(depthsense_metrics::EvalConfig::default()).unwrap();
    let gt = [10.0f32, 20.0, 0.0, 30.0];
    let pred = [11.0f32, 18.0, 5.0, 30.0];
    ev.add(&depthsense_metrics::EvalImage {
        pred_m: &pred,
        gt_m: &gt,
        lowheight: None,
        conditions: &["day"],
    })
    .unwrap();
    let report = ev.finish();
    let doc = depthsense_metrics::tables::report_doc(&[("m", &report)]);
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("tables.json");
    let t = TablesRecord::new(
        &[("m", &report)],
        json!({}),
        Some("depthsense eval"),
        &doc,
        &p,
    )
    .unwrap();
    assert_eq!(t.format_version, TABLES_VERSION);
    std::fs::write(&p, depthsense_records::to_json_pretty(&t).unwrap()).unwrap();
    let back: TablesRecord = read_json(&p).unwrap();
    assert_eq!(back, t);
    // The report inside is the metrics crate's, whole.
    let r: depthsense_metrics::Report =
        serde_json::from_value(serde_json::to_value(&back.models[0].report).unwrap()).unwrap();
    assert_eq!(r, report);
    assert_eq!(
        back.models[0].headline().unwrap().metrics.rmse,
        report.headline().unwrap().metrics.rmse
    );

    let mut incomplete = old;
    incomplete["models"][0]["report"]["rows"][1]["metrics"]
        .as_object_mut()
        .unwrap()
        .remove("mae");
    let e = checked::<TablesRecord>(incomplete, Path::new("tables.json"), None).unwrap_err();
    assert_eq!(
        e.to_string(),
        "tables.json: field \"models[0].report.rows[1].metrics.mae\": missing"
    );
}

#[test]
fn a_sidecar_reads_and_writes_back_the_same_json() {
    let v = json!({"format_version": "depthsense-export-v1", "format": "onnx", "precision": "fp32",
                   "batch": "dynamic", "preset": "tiny", "checkpoint": "runs/a/best.safetensors",
                   "checkpoint_sha256": "0123", "depthsense_version": "0.1.0",
                   "inputs": [{"name": "image", "dtype": "float32", "shape": ["N", 3, 350, 800],
                               "meaning": "RGB"}],
                   "output": {"name": "depth", "dtype": "float32", "shape": ["N", 1, 350, 800],
                              "meaning": "m"},
                   "trained_radar": {"radar_sweeps": 5, "radar_channels": ["RADAR_FRONT"],
                                     "radar_filters": true, "radar_velocity_compensation": false},
                   "sid": {"k": 80}});
    let s: SidecarRecord = checked(v.clone(), Path::new("m.onnx.json"), None).unwrap();
    assert_eq!(s.inputs[0].words(), "`image` [N, 3, 350, 800]");
    assert_eq!(serde_json::to_value(&s).unwrap(), v);
    let mut newer = v.clone();
    newer["format_version"] = json!("depthsense-export-v2");
    let e = checked::<SidecarRecord>(newer, Path::new("m.onnx.json"), None).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("format_version"));
    let mut incomplete = v;
    incomplete["output"]
        .as_object_mut()
        .unwrap()
        .remove("shape");
    let e = checked::<SidecarRecord>(incomplete, Path::new("m.onnx.json"), None).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("output.shape"));
}
