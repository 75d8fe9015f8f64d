//! Training runs, exported models and the tables that compare every model found.
//!
//! - A training run (`train` or `mer train`): a folder with `config.json` and `metrics.jsonl`;
//!   its section shows the command that started it (`"command"` of config.json, when
//!   recorded), the settings, every validation and `curves.png`, and marks a run that stopped
//!   before its last epoch "unfinished".
//! - An exported model: `FILE` beside its sidecar `FILE.json` (`"format_version":
//!   "depthsense-export-v1"`, `depthsense export`); its section shows the format, the tensors and
//!   the radar the network was trained on.
//! - The comparison, at the top of the page: one table of the models scored on test scenes —
//!   the headline row of each `tables.json` (combined conditions, full image, largest cap), the
//!   demo's two models, every arm of an ablation, reduced-data or data-scale experiment (mean
//!   over its seeds) — with the best value of each metric in bold among the rows that share a
//!   test set; then, in a table of its own, the best validation of each training run (it chose
//!   a checkpoint and compares nothing).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use depthsense_metrics::doc::Doc;
use depthsense_metrics::table::{Align, MdTable};
use depthsense_records::metrics_log::{self, BadLine, MetricsRecord, PdaValRecord, ValRecord};
use depthsense_records::run_config::{Command, RunConfig, RunOptions, TrainRunConfig};
use depthsense_records::sidecar::{sidecar_version, SidecarRecord, TensorShape};
use depthsense_records::tables::{HeadlineMetrics, TablesRecord};
use depthsense_records::{json_number, RecordError};
use serde_json::Value;

use super::found::{file_name, read_json, string_at, Found, ImageSource, ModelRow, Split};
use super::Kind;

/// The metrics of the comparison: (column title, decimals, higher is better). RMSE, MAE and
/// AbsRel are errors (lower is better); δ1 is the share of pixels within 1.25× (higher).
const METRIC_COLUMNS: [(&str, usize, bool); 4] = [
    ("RMSE (m)", 3, false),
    ("MAE (m)", 3, false),
    ("AbsRel", 3, false),
    ("δ1", 3, true),
];

fn num(v: &Value, k: &str) -> Option<f64> {
    v.get(k).and_then(Value::as_f64)
}

fn cell(x: Option<f64>, decimals: usize) -> String {
    x.filter(|v| v.is_finite())
        .map_or("–".into(), |v| format!("{v:.decimals$}"))
}

/// The invocation config.json records (`"command"`: the argv, program name first) as one
/// shell line (words quoted where a shell would need it); `None` for a run written before the
/// command was recorded.
pub fn recorded_command(cfg: &RunConfig) -> Option<String> {
    cfg.command().and_then(Command::shell_line)
}

/// A run that stopped before its last epoch (interrupted, `--stop-after`, or still running):
/// the mark shown beside it. Its epochs are the last `"kind":"epoch"` record of metrics.jsonl
/// against the run's `epochs` in config.json (an `--extend`ed run: the new total).
pub fn unfinished<V>(cfg: &RunConfig, records: &[MetricsRecord<V>]) -> Option<String> {
    let total = cfg.options().epochs;
    let done = records
        .iter()
        .filter_map(|r| match r {
            MetricsRecord::Epoch(e) => Some(e.epoch),
            _ => None,
        })
        .max()
        .unwrap_or(0);
    (done < total).then(|| format!("unfinished (epoch {done} of {total}; continue with --resume)"))
}

/// The section of a training run in `dir` (`config.json` + `metrics.jsonl`); `None` when `dir`
/// is not one, `Err` (the file and the reason) when one of its records cannot be read: a
/// missing or mistyped field is named, never shown as a value.
pub fn training_run(
    dir: &Path,
    files: &[PathBuf],
    names: &BTreeSet<&str>,
) -> Option<Result<Found, (PathBuf, String)>> {
    if !names.contains("config.json") || !names.contains("metrics.jsonl") {
        return None;
    }
    Some(read_training_run(dir, files, names).map_err(|e| (e.path.clone(), e.reason())))
}

fn read_training_run(
    dir: &Path,
    files: &[PathBuf],
    names: &BTreeSet<&str>,
) -> Result<Found, RecordError> {
    let cfg = RunConfig::read(&dir.join("config.json"))?;
    let log_path = dir.join("metrics.jsonl");
    let text = std::fs::read_to_string(&log_path)
        .map_err(|e| RecordError::new(&log_path, format!("cannot read: {e}")))?;
    // A line that is not JSON is half a line of a run killed mid-write: left out.
    let lines = metrics_log::json_lines(&text, &log_path, BadLine::Skip)?;
    let pda = metrics_log::holds_pda(&lines);
    let mut f = Found {
        kind: Kind::Train,
        dir: dir.to_path_buf(),
        files: run_files(files),
        command_line: recorded_command(&cfg),
        inputs: vec![
            ("data".into(), cfg.options().data.clone()),
            ("out".into(), cfg.options().out.clone()),
        ],
        doc: Doc::new(),
        images: vec![],
        grid: None,
        models: vec![],
    };
    f.doc = if pda {
        let recs = metrics_log::typed::<PdaValRecord>(lines, &log_path)?;
        pda_doc(&cfg, &recs, unfinished(&cfg, &recs).as_deref())
    } else {
        let recs = metrics_log::typed::<ValRecord>(lines, &log_path)?;
        let RunConfig::Train(train) = &cfg else {
            return Err(RecordError {
                path: dir.join("config.json"),
                line: None,
                field: Some("mer_train".into()),
                problem: "a `mer train` run whose metrics.jsonl holds no PDA validation".into(),
            });
        };
        let (doc, best) = depth_doc(dir, train, &recs, unfinished(&cfg, &recs));
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
    Ok(f)
}

/// The files of `files` a training run's section lists: its records, its curves and its
/// checkpoints.
fn run_files(files: &[PathBuf]) -> Vec<PathBuf> {
    files
        .iter()
        .filter(|p| {
            let n = file_name(p).unwrap_or_default();
            n == "config.json"
                || n == "metrics.jsonl"
                || n == "curves.png"
                || n.ends_with(".safetensors")
        })
        .cloned()
        .collect()
}

/// The iteration cell of a validation row ("–": an epoch line written without it).
fn iteration_cell(it: Option<u64>) -> String {
    it.map_or("–".into(), |i| i.to_string())
}

/// A depth network's run: settings, every validation, and its best validation as a model row.
fn depth_doc(
    dir: &Path,
    cfg: &TrainRunConfig,
    recs: &[MetricsRecord<ValRecord>],
    unfinished: Option<String>,
) -> (Doc, Option<ModelRow>) {
    let mut doc = Doc::new();
    depth_settings(&mut doc, cfg, unfinished.as_deref());
    doc.table(validation_table(recs));
    let best = best_validation(dir, cfg, recs, unfinished);
    (doc, best)
}

/// The paragraphs of a depth network's run: the network, schedule and data, and where it was
/// initialised from or extended.
fn depth_settings(doc: &mut Doc, cfg: &TrainRunConfig, unfinished: Option<&str>) {
    let t = &cfg.train;
    let m = &cfg.model;
    doc.paragraph(format!(
        "`{}` ({}), {} batch {}, lr {}, seed {}, on `{}` ({} training / {} \
         validation samples used).",
        m.name,
        m.fusion_words(),
        epochs_text(t, unfinished),
        t.batch_size,
        json_number(t.lr),
        t.seed,
        t.data,
        cfg.partition.train_samples,
        cfg.partition.val_samples_used,
    ));
    if let Some(init) = &cfg.init_from {
        doc.paragraph(format!(
            "Initialised from `{}` ({} tensors loaded, {} new).",
            init.file,
            init.loaded,
            init.new.len()
        ));
    }
    if !cfg.schedule.is_empty() {
        doc.paragraph(format!(
            "Extended (`train --extend`): {} learning-rate segments.",
            cfg.schedule.len()
        ));
    }
}

/// One row per validation of a depth network's run (metres, δ1 a share).
fn validation_table(recs: &[MetricsRecord<ValRecord>]) -> MdTable {
    let mut t = right_aligned(&[
        "epoch",
        "iteration",
        "val RMSE (m)",
        "MAE (m)",
        "AbsRel",
        "δ1",
        "images",
    ]);
    let vals: Vec<(u64, Option<u64>, &ValRecord)> =
        recs.iter().filter_map(MetricsRecord::validation).collect();
    for (epoch, it, v) in &vals {
        t.row(&[
            epoch.to_string(),
            iteration_cell(*it),
            cell(Some(v.rmse), 3),
            cell(Some(v.mae), 3),
            cell(Some(v.abs_rel), 3),
            cell(Some(v.delta1), 3),
            v.n_images.to_string(),
        ]);
    }
    t
}

/// The comparison's row of a depth network's run: its epoch-end validation of lowest RMSE
/// (metres); `None` when no epoch ended with a finite one.
fn best_validation(
    dir: &Path,
    cfg: &TrainRunConfig,
    recs: &[MetricsRecord<ValRecord>],
    unfinished: Option<String>,
) -> Option<ModelRow> {
    recs.iter()
        .filter(|r| matches!(r, MetricsRecord::Epoch(_)))
        .filter_map(MetricsRecord::validation)
        .filter(|(_, _, v)| v.rmse.is_finite())
        .min_by(|a, b| a.2.rmse.total_cmp(&b.2.rmse))
        .map(|(epoch, _, v)| ModelRow {
            name: dir
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            split: Split::Validation,
            rows: format!("best epoch ({epoch})"),
            dir: dir.to_path_buf(),
            data: Some(cfg.train.data.clone()),
            cap_m: None,
            seeds: Some(1),
            unfinished: unfinished.clone(),
            images: Some(v.n_images),
            rmse_m: Some(v.rmse),
            mae_m: Some(v.mae),
            abs_rel: Some(v.abs_rel),
            delta1: Some(v.delta1),
        })
}

/// "10 epochs of", or for a run that stopped early its mark in bold: "**unfinished (epoch 3
/// of 10; continue with --resume)**,".
fn epochs_text(t: &RunOptions, unfinished: Option<&str>) -> String {
    match unfinished {
        Some(mark) => format!("**{mark}**,"),
        None => format!("{} epochs of", t.epochs),
    }
}

/// A table whose columns are all numbers (right-aligned).
fn right_aligned(titles: &[&str]) -> MdTable {
    let cols: Vec<(&str, Align)> = titles.iter().map(|t| (*t, Align::Right)).collect();
    MdTable::new(&cols)
}

/// A PDA (MER) run: every validation's association metrics.
fn pda_doc(cfg: &RunConfig, recs: &[MetricsRecord<PdaValRecord>], unfinished: Option<&str>) -> Doc {
    let t = cfg.options();
    let mut doc = Doc::new();
    doc.paragraph(format!(
        "PDA network (MER, SPEC §5), {} batch {}, lr {}, on `{}`.",
        epochs_text(t, unfinished),
        t.batch_size,
        json_number(t.lr),
        t.data,
    ));
    let mut t = right_aligned(&[
        "epoch",
        "iteration",
        "val loss",
        "AUC",
        "precision",
        "recall",
    ]);
    for (epoch, it, v) in recs.iter().filter_map(MetricsRecord::validation) {
        t.row(&[
            epoch.to_string(),
            iteration_cell(it),
            cell(Some(v.loss), 4),
            cell(Some(v.auc), 4),
            cell(Some(v.precision), 3),
            cell(Some(v.recall), 3),
        ]);
    }
    doc.table(t);
    doc
}

/// Exported models of `dir`: every `FILE.json` that is an export sidecar, with `FILE`. A
/// sidecar that cannot be read (a field missing, a newer format) goes to `skipped` with its
/// file and field.
pub fn exports(
    dir: &Path,
    files: &[PathBuf],
    claimed: &mut BTreeSet<PathBuf>,
    skipped: &mut Vec<(PathBuf, String)>,
) -> Vec<Found> {
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
        // A sidecar of depthsense says so; any other JSON beside a file is not one.
        let Some(_) = v["format_version"].as_str().and_then(sidecar_version) else {
            continue;
        };
        claimed.insert(sidecar.clone());
        claimed.insert(model.clone());
        let record: SidecarRecord = match depthsense_records::checked(v, sidecar, None) {
            Ok(r) => r,
            Err(e) => {
                skipped.push((sidecar.clone(), e.reason()));
                continue;
            }
        };
        out.push(Found {
            kind: Kind::Export,
            dir: dir.to_path_buf(),
            files: vec![model.clone(), sidecar.clone()],
            command_line: None,
            inputs: vec![("checkpoint".into(), record.checkpoint.clone())],
            doc: export_doc(&model, &record),
            images: vec![],
            grid: None,
            models: vec![],
        });
    }
    out
}

fn export_doc(model: &Path, v: &SidecarRecord) -> Doc {
    let inputs: Vec<String> = v.inputs.iter().map(TensorShape::words).collect();
    let bytes = std::fs::metadata(model).map_or(0, |m| m.len());
    let mut doc = Doc::new();
    doc.paragraph(format!(
        "`{}`: {} ({}, batch {}), {:.1} MB, preset `{}`; inputs {}; output {} in metres. From \
         `{}` (SHA-256 {}…).",
        file_name(model).unwrap_or("?"),
        v.format,
        v.precision,
        v.batch,
        bytes as f64 / 1e6,
        v.preset,
        inputs.join(", "),
        v.output.words(),
        v.checkpoint,
        v.checkpoint_sha256.chars().take(12).collect::<String>(),
    ));
    if let Some(r) = &v.trained_radar {
        let on = |b: bool| if b { "on" } else { "off" };
        doc.paragraph(format!(
            "Trained on radar of {} sweep(s) per channel ({}), devkit filters {}, velocity \
             compensation {}: feed it radar gathered the same way.",
            r.radar_sweeps,
            r.radar_channels.join(", "),
            on(r.radar_filters),
            on(r.radar_velocity_compensation),
        ));
    }
    doc
}

/// Each model of an evaluation's `tables.json` (`eval`, or the demo's) as a test row of the
/// comparison: its headline row (combined conditions, full image, largest cap). `data`: the
/// prepared folder it was scored on, when known; `from`: what wrote it.
pub fn eval_models(
    dir: &Path,
    v: &TablesRecord,
    data: Option<String>,
    from: &str,
) -> Vec<ModelRow> {
    v.models
        .iter()
        .map(|m| {
            let head = m.headline();
            let metric = |f: fn(&HeadlineMetrics) -> f64| head.map(|r| f(&r.metrics));
            ModelRow {
                name: m.name.clone(),
                split: Split::Test,
                rows: from.to_string(),
                dir: dir.to_path_buf(),
                data: data.clone(),
                cap_m: head.map(|r| r.cap_m),
                // One checkpoint: one training seed.
                seeds: Some(1),
                unfinished: None,
                images: head.map(|r| r.n_images),
                rmse_m: metric(|m| m.rmse),
                mae_m: metric(|m| m.mae),
                abs_rel: metric(|m| m.abs_rel),
                delta1: metric(|m| m.delta1),
            }
        })
        .collect()
}

/// Every arm of an experiment of many training runs (`ablation.json`: each variant;
/// `reduced_data.json`: each training-set cell; `data_scale.json`: each arm at each N) as a
/// test row of the comparison: its mean over seeds on the combined conditions, full image,
/// largest cap.
pub fn experiment_models(kind: Kind, dir: &Path, v: &Value) -> Vec<ModelRow> {
    let data = string_at(v, &["options", "data"]);
    let images = shared_test_images(v);
    let mean = |r: &Value, k: &str| num(&r[k], "mean");
    let row = |name: String, r: &Value, cap_m: Option<f64>| ModelRow {
        name,
        split: Split::Test,
        rows: kind.slug().replace('-', " "),
        dir: dir.to_path_buf(),
        data: data.clone(),
        cap_m,
        seeds: r["rmse"]["n"].as_u64().map(|n| n as usize),
        unfinished: None,
        images,
        rmse_m: mean(r, "rmse"),
        mae_m: mean(r, "mae"),
        abs_rel: mean(r, "abs_rel"),
        delta1: mean(r, "delta1"),
    };
    match kind {
        Kind::Ablation | Kind::ReducedData => largest_cap_rows(v)
            .into_iter()
            .map(|(variant, r)| {
                let name = match kind {
                    Kind::ReducedData => format!("trained on {variant}"),
                    _ => variant,
                };
                row(name, r, num(r, "cap_m"))
            })
            .collect(),
        Kind::DataScale => {
            let cap = v["options"]["eval"]["caps_m"]
                .as_array()
                .and_then(|c| c.iter().filter_map(Value::as_f64).reduce(f64::max));
            v["rows"]
                .as_array()
                .into_iter()
                .flatten()
                .map(|r| {
                    let name = format!(
                        "{}, N = {}",
                        r["arm"].as_str().unwrap_or("?"),
                        r["train_samples"]
                    );
                    row(name, r, cap)
                })
                .collect()
        }
        _ => vec![],
    }
}

/// The test image count every run of an experiment shares (each is tested on the same
/// scenes): its combined / full-image rows' `n_images`, `None` unless exactly one count.
fn shared_test_images(v: &Value) -> Option<u64> {
    let images: BTreeSet<u64> = v["runs"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|r| {
            r["rows"].as_array()?.iter().find_map(|x| {
                (x["condition"] == "combined" && x["region"] == "full")
                    .then(|| x["n_images"].as_u64())
                    .flatten()
            })
        })
        .collect();
    (images.len() == 1)
        .then(|| images.into_iter().next())
        .flatten()
}

/// Each variant's (cell's) combined / full-image summary row at its largest cap (metres), in
/// the order the variants first appear.
fn largest_cap_rows(v: &Value) -> Vec<(String, &Value)> {
    let mut best: Vec<(String, &Value)> = vec![];
    for r in v["summary"].as_array().into_iter().flatten() {
        if r["condition"] != "combined" || r["region"] != "full" {
            continue;
        }
        let Some(variant) = r["variant"].as_str() else {
            continue;
        };
        match best.iter_mut().find(|(n, _)| n == variant) {
            Some((_, b)) if num(r, "cap_m") > num(b, "cap_m") => *b = r,
            Some(_) => {}
            None => best.push((variant.to_string(), r)),
        }
    }
    best
}

/// For each row, which of its metrics ([`METRIC_COLUMNS`]) is the best among the rows of its
/// test set ([`ModelRow::test_set`]; ties all marked; a test set of one row marks nothing).
fn best_marks(rows: &[&ModelRow]) -> Vec<[bool; 4]> {
    let mut marks = vec![[false; 4]; rows.len()];
    for (i, r) in rows.iter().enumerate() {
        let peers: Vec<&ModelRow> = rows
            .iter()
            .filter(|p| p.test_set() == r.test_set())
            .copied()
            .collect();
        if peers.len() < 2 {
            continue;
        }
        for (k, &(_, decimals, higher)) in METRIC_COLUMNS.iter().enumerate() {
            // Compared as shown: values equal to the shown decimals tie.
            let shown = |m: &ModelRow| {
                m.metrics()[k]
                    .filter(|x| x.is_finite())
                    .and_then(|x| format!("{x:.decimals$}").parse::<f64>().ok())
            };
            let Some(mine) = shown(r) else { continue };
            let best = peers.iter().filter_map(|p| shown(p)).reduce(|a, b| {
                if higher {
                    a.max(b)
                } else {
                    a.min(b)
                }
            });
            marks[i][k] = best == Some(mine);
        }
    }
    marks
}

/// The comparison section over every model row of `sections`, or `None` without any: the test
/// rows (best of each metric in bold), then the validation rows in a table of their own.
pub fn comparison(sections: &[Found]) -> Option<Found> {
    let all: Vec<&ModelRow> = sections.iter().flat_map(|s| &s.models).collect();
    if all.is_empty() {
        return None;
    }
    let mut test: Vec<&ModelRow> = all
        .iter()
        .filter(|r| r.split == Split::Test)
        .copied()
        .collect();
    // Rows of one test set together (stable: each set in the order found).
    let order: Vec<_> = test.iter().map(|r| r.test_set()).collect();
    test.sort_by_key(|r| {
        let key = r.test_set();
        order.iter().position(|k| *k == key)
    });
    let val: Vec<&ModelRow> = all
        .iter()
        .filter(|r| r.split == Split::Validation)
        .copied()
        .collect();
    let mut doc = Doc::new();
    test_rows_doc(&mut doc, &test);
    validation_rows_doc(&mut doc, &val);
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

/// "Test scenes": the rows grouped by test set, the best of each metric in bold.
fn test_rows_doc(doc: &mut Doc, test: &[&ModelRow]) {
    doc.heading(1, "Test scenes");
    if test.is_empty() {
        doc.paragraph(
            "No model was scored on test scenes: `depthsense eval --checkpoint RUN/best.safetensors` \
             scores one; the validation rows below chose checkpoints and compare nothing.",
        );
        return;
    }
    doc.paragraph(
        "Every model scored on test scenes (scenes no choice was made on): the headline row \
         of each evaluation and of the demo (combined conditions, full image, largest cap) \
         and every arm of an experiment (mean over its seeds). **Bold**: the best value of \
         each metric among the rows of one test set (same data, cap and images); lower is \
         better for RMSE, MAE and AbsRel, higher for δ1.",
    );
    let marks = best_marks(test);
    let mut t = MdTable::new(&test_columns());
    for (r, m) in test.iter().zip(&marks) {
        let mut cells = vec![
            r.name.clone(),
            r.rows.clone(),
            format!("`{}`", r.dir.display()),
            r.data.as_ref().map_or("–".into(), |d| format!("`{d}`")),
            r.cap_m.map_or("–".into(), |c| format!("{c}")),
            r.seeds.map_or("–".into(), |n| n.to_string()),
            r.images.map_or("–".into(), |n| n.to_string()),
        ];
        for (k, &(_, decimals, _)) in METRIC_COLUMNS.iter().enumerate() {
            let c = cell(r.metrics()[k], decimals);
            cells.push(if m[k] { format!("**{c}**") } else { c });
        }
        t.row(&cells);
    }
    doc.table(t);
    if let Some(text) = one_seed_caveat(test) {
        doc.paragraph(text);
    }
}

/// "Validation (checkpoint selection)": each training run's best epoch, unfinished runs marked.
fn validation_rows_doc(doc: &mut Doc, val: &[&ModelRow]) {
    if val.is_empty() {
        return;
    }
    doc.heading(1, "Validation (checkpoint selection)");
    doc.paragraph(
        "The best validation of each training run: it chose the run's `best.safetensors` \
         and is no comparison of methods (evaluate the checkpoint on the test scenes for \
         that). An unfinished run stopped before its last epoch.",
    );
    let mut cols = vec![
        ("model", Align::Left),
        ("folder", Align::Left),
        ("epoch", Align::Left),
        ("run", Align::Left),
        ("images", Align::Right),
    ];
    cols.extend(METRIC_COLUMNS.iter().map(|(t, ..)| (*t, Align::Right)));
    let mut t = MdTable::new(&cols);
    for r in val {
        let mut cells = vec![
            r.name.clone(),
            format!("`{}`", r.dir.display()),
            r.rows.clone(),
            r.unfinished
                .as_ref()
                .map_or("finished".into(), |u| format!("**{u}**")),
            r.images.map_or("–".into(), |n| n.to_string()),
        ];
        for (k, &(_, decimals, _)) in METRIC_COLUMNS.iter().enumerate() {
            cells.push(cell(r.metrics()[k], decimals));
        }
        t.row(&cells);
    }
    doc.table(t);
}

fn test_columns() -> Vec<(&'static str, Align)> {
    let mut cols = vec![
        ("model", Align::Left),
        ("from", Align::Left),
        ("folder", Align::Left),
        ("data", Align::Left),
        ("cap (m)", Align::Right),
        ("seeds", Align::Right),
        ("images", Align::Right),
    ];
    cols.extend(METRIC_COLUMNS.iter().map(|(t, ..)| (*t, Align::Right)));
    cols
}

/// When a row of one seed has a peer in its test set (a difference between them rests on one
/// seed): the words that say so.
fn one_seed_caveat(rows: &[&ModelRow]) -> Option<String> {
    let names: Vec<String> = rows
        .iter()
        .filter(|r| r.seeds.is_none_or(|n| n <= 1))
        .filter(|r| rows.iter().filter(|p| p.test_set() == r.test_set()).count() > 1)
        .map(|r| format!("`{}`", r.name))
        .collect();
    if names.is_empty() {
        return None;
    }
    Some(format!(
        "**One seed**: {} {} one trained model each; a difference between such rows is one \
         seed: not a finding. An experiment's arms (mean over seeds, with its paired test) are \
         the comparison.",
        names.join(", "),
        if names.len() == 1 { "is" } else { "are" },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    const OPTIONS: &str = r#""data": "p", "out": "r", "batch_size": 4, "lr": 0.002, "seed": 7"#;

    /// A config.json of `train` (`"train"`) or `mer train` (`"mer_train"`) with `epochs` and
    /// the `command` given.
    fn config(key: &str, epochs: u64, command: Option<Value>) -> RunConfig {
        let mut v: Value = serde_json::from_str(&format!(
            r#"{{"{key}": {{{OPTIONS}, "epochs": {epochs}}},
                "model": {{"name": "tiny", "fusion": "late", "attention": true}},
                "partition": {{"train_samples": 1, "val_samples_used": 1}}}}"#
        ))
        .unwrap();
        if let Some(c) = command {
            v["command"] = c;
        }
        RunConfig::from_value(v, Path::new("config.json")).unwrap()
    }

    /// config.json's argv as one line a shell reads back to the same words.
    #[test]
    fn the_recorded_command_is_one_shell_line() {
        let cfg = config(
            "train",
            1,
            Some(json!([
                "depthsense",
                "train",
                "--set",
                "a=1",
                "--out",
                "it's here",
                ""
            ])),
        );
        assert_eq!(
            recorded_command(&cfg).as_deref(),
            Some("depthsense train --set a=1 --out 'it'\\''s here' ''")
        );
        assert_eq!(recorded_command(&config("train", 1, Some(json!([])))), None);
        assert_eq!(recorded_command(&config("train", 1, None)), None);
        assert_eq!(
            recorded_command(&config("mer_train", 1, Some(json!("depthsense mer train"))))
                .as_deref(),
            Some("depthsense mer train")
        );
    }

    /// Unfinished: the last epoch record before the run's epochs (`mer train`'s config too).
    #[test]
    fn a_run_short_of_its_epochs_is_unfinished() {
        let recs: Vec<MetricsRecord<ValRecord>> = [
            json!({"kind": "epoch", "epoch": 2}),
            json!({"kind": "iter", "epoch": 2, "iteration": 9, "loss": 1.0}),
        ]
        .into_iter()
        .map(|v| serde_json::from_value(v).unwrap())
        .collect();
        let mark = "unfinished (epoch 2 of 5; continue with --resume)";
        assert_eq!(
            unfinished(&config("train", 5, None), &recs).as_deref(),
            Some(mark)
        );
        assert_eq!(
            unfinished(&config("mer_train", 5, None), &recs).as_deref(),
            Some(mark)
        );
        assert_eq!(unfinished(&config("train", 2, None), &recs), None);
        assert_eq!(
            unfinished::<ValRecord>(&config("train", 2, None), &[]).as_deref(),
            Some("unfinished (epoch 0 of 2; continue with --resume)")
        );
    }
}
