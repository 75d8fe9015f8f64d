//! Training runs, exported models and the table that compares every model found.
//!
//! - A training run (`train` or `mer train`): a folder with `config.json` and `metrics.jsonl`;
//!   its section shows the settings, every validation and `curves.png`.
//! - An exported model: `FILE` beside its sidecar `FILE.json` (`"format_version":
//!   "depthsense-export-v1"`, `depthsense export`); its section shows the format, the tensors and
//!   the radar the network was trained on.
//! - The comparison: one row per evaluated model (the headline row of each `tables.json`: test
//!   scenes, combined conditions, full image, largest cap) and per training run (its best
//!   validation), at the top of the page.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use depthsense_metrics::doc::Doc;
use depthsense_metrics::table::{Align, MdTable};
use serde_json::Value;

use super::discover::{file_name, read_json, string_at, Found, ImageSource};
use super::Kind;

/// The sidecar format `depthsense export` writes.
const SIDECAR_FORMAT: &str = "depthsense-export-v1";

/// One model of the comparison table.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelRow {
    pub name: String,
    /// `test (eval)` or `validation (best of N epochs)`.
    pub rows: String,
    pub dir: PathBuf,
    pub images: Option<u64>,
    pub rmse_m: Option<f64>,
    pub mae_m: Option<f64>,
    pub abs_rel: Option<f64>,
    pub delta1: Option<f64>,
}

/// The records of a `metrics.jsonl` (lines that are not JSON are left out).
fn records(p: &Path) -> Vec<Value> {
    std::fs::read_to_string(p)
        .map(|t| {
            t.lines()
                .filter_map(|l| serde_json::from_str(l).ok())
                .collect()
        })
        .unwrap_or_default()
}

fn num(v: &Value, k: &str) -> Option<f64> {
    v.get(k).and_then(Value::as_f64)
}

fn cell(x: Option<f64>, decimals: usize) -> String {
    x.filter(|v| v.is_finite())
        .map_or("–".into(), |v| format!("{v:.decimals$}"))
}

/// The section of a training run in `dir` (`config.json` + `metrics.jsonl`), or `None` when
/// `dir` is not one.
pub fn training_run(dir: &Path, files: &[PathBuf], names: &BTreeSet<&str>) -> Option<Found> {
    if !names.contains("config.json") || !names.contains("metrics.jsonl") {
        return None;
    }
    let cfg = read_json(&dir.join("config.json")).ok()?;
    let recs = records(&dir.join("metrics.jsonl"));
    let vals: Vec<&Value> = recs
        .iter()
        .filter(|r| r["kind"] == "val" || (r["kind"] == "epoch" && r.get("val").is_some()))
        .collect();
    let pda = vals.iter().any(|r| r["val"].get("auc").is_some());
    let mut f = Found {
        kind: Kind::Train,
        dir: dir.to_path_buf(),
        files: files
            .iter()
            .filter(|p| {
                let n = file_name(p).unwrap_or_default();
                n == "config.json"
                    || n == "metrics.jsonl"
                    || n == "curves.png"
                    || n.ends_with(".safetensors")
            })
            .cloned()
            .collect(),
        command_line: None,
        inputs: ["data", "out"]
            .iter()
            .filter_map(|k| string_at(&cfg, &["train", k]).map(|v| (k.to_string(), v)))
            .collect(),
        doc: Doc::new(),
        images: vec![],
        grid: None,
        models: vec![],
    };
    f.doc = if pda {
        pda_doc(&cfg, &vals)
    } else {
        let (doc, best) = depth_doc(dir, &cfg, &vals);
        f.models.extend(best);
        doc
    };
    if names.contains("curves.png") {
        f.images.push(ImageSource {
            path: dir.join("curves.png"),
            caption: "curves.png: training loss and validation".into(),
            tile: false,
        });
    }
    Some(f)
}

/// A depth network's run: settings, every validation, and its best validation as a model row.
fn depth_doc(dir: &Path, cfg: &Value, vals: &[&Value]) -> (Doc, Option<ModelRow>) {
    let t = &cfg["train"];
    let m = &cfg["model"];
    let fusion = match (m["fusion"].as_str(), m["attention"].as_bool()) {
        (Some("late"), Some(true)) => "late fusion + attention",
        (Some("late"), _) => "late fusion",
        (Some("early"), _) => "early fusion",
        _ => "RGB only",
    };
    let mut doc = Doc::new();
    doc.paragraph(format!(
        "`{}` ({fusion}), {} epochs of batch {}, lr {}, seed {}, on `{}` ({} training / {} \
         validation samples used).",
        m["name"].as_str().unwrap_or("?"),
        t["epochs"],
        t["batch_size"],
        t["lr"],
        t["seed"],
        t["data"].as_str().unwrap_or("?"),
        cfg["partition"]["train_samples"],
        cfg["partition"]["val_samples_used"],
    ));
    if let Some(init) = cfg.get("init_from") {
        doc.paragraph(format!(
            "Initialised from `{}` ({} tensors loaded, {} new).",
            init["file"].as_str().unwrap_or("?"),
            init["loaded"],
            init["new"].as_array().map_or(0, Vec::len)
        ));
    }
    if let Some(segments) = cfg.get("schedule").and_then(Value::as_array) {
        doc.paragraph(format!(
            "Extended (`train --extend`): {} learning-rate segments.",
            segments.len()
        ));
    }
    let mut t = right_aligned(&[
        "epoch",
        "iteration",
        "val RMSE (m)",
        "MAE (m)",
        "AbsRel",
        "δ1",
        "images",
    ]);
    for r in vals {
        let v = &r["val"];
        t.row(&[
            r["epoch"].to_string(),
            r["iteration"].to_string(),
            cell(num(v, "rmse"), 3),
            cell(num(v, "mae"), 3),
            cell(num(v, "abs_rel"), 3),
            cell(num(v, "delta1"), 3),
            v["n_images"].to_string(),
        ]);
    }
    doc.table(t);
    let best = vals
        .iter()
        .filter(|r| r["kind"] == "epoch")
        .filter_map(|r| Some((num(&r["val"], "rmse")?, *r)))
        .filter(|(x, _)| x.is_finite())
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, r)| ModelRow {
            name: dir
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            rows: format!("validation, best epoch ({})", r["epoch"]),
            dir: dir.to_path_buf(),
            images: r["val"]["n_images"].as_u64(),
            rmse_m: num(&r["val"], "rmse"),
            mae_m: num(&r["val"], "mae"),
            abs_rel: num(&r["val"], "abs_rel"),
            delta1: num(&r["val"], "delta1"),
        });
    (doc, best)
}

/// A table whose columns are all numbers (right-aligned).
fn right_aligned(titles: &[&str]) -> MdTable {
    let cols: Vec<(&str, Align)> = titles.iter().map(|t| (*t, Align::Right)).collect();
    MdTable::new(&cols)
}

/// A PDA (MER) run: every validation's association metrics.
fn pda_doc(cfg: &Value, vals: &[&Value]) -> Doc {
    let mut doc = Doc::new();
    doc.paragraph(format!(
        "PDA network (MER, SPEC §5), {} epochs of batch {}, lr {}, on `{}`.",
        cfg["train"]["epochs"],
        cfg["train"]["batch_size"],
        cfg["train"]["lr"],
        cfg["train"]["data"].as_str().unwrap_or("?"),
    ));
    let mut t = right_aligned(&[
        "epoch",
        "iteration",
        "val loss",
        "AUC",
        "precision",
        "recall",
    ]);
    for r in vals {
        let v = &r["val"];
        t.row(&[
            r["epoch"].to_string(),
            r["iteration"].to_string(),
            cell(num(v, "loss"), 4),
            cell(num(v, "auc"), 4),
            cell(num(v, "precision"), 3),
            cell(num(v, "recall"), 3),
        ]);
    }
    doc.table(t);
    doc
}

/// Exported models of `dir`: every `FILE.json` that is an export sidecar, with `FILE`.
pub fn exports(dir: &Path, files: &[PathBuf], claimed: &mut BTreeSet<PathBuf>) -> Vec<Found> {
    let mut out = vec![];
    for sidecar in files {
        let Some(model) = file_name(sidecar)
            .and_then(|n| n.strip_suffix(".json"))
            .map(|n| dir.join(n))
        else {
            continue;
        };
        if !model.is_file() || claimed.contains(sidecar) {
            continue;
        }
        let Ok(v) = read_json(sidecar) else { continue };
        if v["format_version"] != SIDECAR_FORMAT {
            continue;
        }
        claimed.insert(sidecar.clone());
        claimed.insert(model.clone());
        out.push(Found {
            kind: Kind::Export,
            dir: dir.to_path_buf(),
            files: vec![model.clone(), sidecar.clone()],
            command_line: None,
            inputs: vec![(
                "checkpoint".into(),
                v["checkpoint"].as_str().unwrap_or("?").into(),
            )],
            doc: export_doc(&model, &v),
            images: vec![],
            grid: None,
            models: vec![],
        });
    }
    out
}

fn export_doc(model: &Path, v: &Value) -> Doc {
    let shape = |t: &Value| {
        let dims: Vec<String> = t["shape"]
            .as_array()
            .map(|a| {
                a.iter()
                    .map(|d| d.as_str().map_or(d.to_string(), str::to_string))
                    .collect()
            })
            .unwrap_or_default();
        format!(
            "`{}` [{}]",
            t["name"].as_str().unwrap_or("?"),
            dims.join(", ")
        )
    };
    let inputs: Vec<String> = v["inputs"]
        .as_array()
        .map(|a| a.iter().map(shape).collect())
        .unwrap_or_default();
    let bytes = std::fs::metadata(model).map_or(0, |m| m.len());
    let mut doc = Doc::new();
    doc.paragraph(format!(
        "`{}`: {} ({}, batch {}), {:.1} MB, preset `{}`; inputs {}; output {} in metres. From \
         `{}` (SHA-256 {}…).",
        file_name(model).unwrap_or("?"),
        v["format"].as_str().unwrap_or("?"),
        v["precision"].as_str().unwrap_or("?"),
        v["batch"].as_str().unwrap_or("?"),
        bytes as f64 / 1e6,
        v["preset"].as_str().unwrap_or("?"),
        inputs.join(", "),
        shape(&v["output"]),
        v["checkpoint"].as_str().unwrap_or("?"),
        v["checkpoint_sha256"]
            .as_str()
            .map_or("?".into(), |h| h.chars().take(12).collect::<String>()),
    ));
    if let Some(r) = v.get("trained_radar") {
        doc.paragraph(format!(
            "Trained on radar of {} sweep(s) per channel ({}), devkit filters {}, velocity \
             compensation {}: feed it radar gathered the same way.",
            r["radar_sweeps"],
            r["radar_channels"]
                .as_array()
                .map(|a| a
                    .iter()
                    .filter_map(Value::as_str)
                    .collect::<Vec<_>>()
                    .join(", "))
                .unwrap_or_default(),
            if r["radar_filters"] == true {
                "on"
            } else {
                "off"
            },
            if r["radar_velocity_compensation"] == true {
                "on"
            } else {
                "off"
            },
        ));
    }
    doc
}

/// Each model of an evaluation's `tables.json` as a row of the comparison.
pub fn eval_models(dir: &Path, v: &Value) -> Vec<ModelRow> {
    let Some(models) = v.get("models").and_then(Value::as_array) else {
        return vec![];
    };
    models
        .iter()
        .map(|m| {
            let head = m["report"]["rows"].as_array().and_then(|rows| {
                rows.iter()
                    .filter(|r| r["condition"] == "combined" && r["region"] == "full")
                    .max_by(|a, b| {
                        num(a, "cap_m")
                            .unwrap_or(0.0)
                            .total_cmp(&num(b, "cap_m").unwrap_or(0.0))
                    })
            });
            let metric = |k: &str| head.and_then(|r| num(&r["metrics"], k));
            ModelRow {
                name: m["name"].as_str().unwrap_or("?").to_string(),
                rows: head.map_or("test".into(), |r| {
                    format!("test, cap {} m", num(r, "cap_m").unwrap_or(f64::NAN))
                }),
                dir: dir.to_path_buf(),
                images: head.and_then(|r| r["n_images"].as_u64()),
                rmse_m: metric("rmse"),
                mae_m: metric("mae"),
                abs_rel: metric("abs_rel"),
                delta1: metric("delta1"),
            }
        })
        .collect()
}

/// The comparison section over every model row of `sections`, or `None` without any.
pub fn comparison(sections: &[Found]) -> Option<Found> {
    let rows: Vec<&ModelRow> = sections.iter().flat_map(|s| &s.models).collect();
    if rows.is_empty() {
        return None;
    }
    let mut doc = Doc::new();
    doc.paragraph(
        "Every model found: the headline row of each evaluation (`tables.json`: combined \
         conditions, full image, largest cap) and the best validation of each training run. \
         Validation rows pick checkpoints; only test rows compare methods.",
    );
    let mut t = MdTable::new(&[
        ("model", Align::Left),
        ("folder", Align::Left),
        ("rows", Align::Left),
        ("images", Align::Right),
        ("RMSE (m)", Align::Right),
        ("MAE (m)", Align::Right),
        ("AbsRel", Align::Right),
        ("δ1", Align::Right),
    ]);
    for r in rows {
        t.row(&[
            r.name.clone(),
            format!("`{}`", r.dir.display()),
            r.rows.clone(),
            r.images.map_or("–".into(), |n| n.to_string()),
            cell(r.rmse_m, 3),
            cell(r.mae_m, 3),
            cell(r.abs_rel, 3),
            cell(r.delta1, 3),
        ]);
    }
    doc.table(t);
    Some(Found {
        kind: Kind::Models,
        dir: PathBuf::new(),
        files: vec![],
        command_line: None,
        inputs: vec![],
        doc,
        images: vec![],
        grid: None,
        models: vec![],
    })
}
