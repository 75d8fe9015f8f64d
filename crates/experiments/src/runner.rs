//! The runner behind the training experiments (`ablation`, `reduced-data`): one run =
//! train (or resume) with [`TrainOptions`], then evaluate its `best.safetensors` (chosen on
//! the validation scenes) on the TEST samples, stored as `RUN/eval.json`. Resumable: a run
//! with a matching `eval.json` is read back; a finished training is only evaluated; any other
//! run continues from its last checkpoint. Options that differ from a stored run are refused.
//! Also the seed summaries ([`summarise`]) the experiments table.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::ExperimentError;
use depthsense_base::fsutil::write_atomic;
use depthsense_checkpoint as checkpoint;
use depthsense_config::training::{
    CheckpointOptions, HardwareOptions, LoadingOptions, ScheduleOptions, ValidationOptions,
};
use depthsense_config::ModelConfig;
use depthsense_data::LoadOptions;
use depthsense_dataset::outputs::{BEST_CKPT, CONFIG_FILE, METRICS_FILE};
use depthsense_dataset::{Dataset, Partition};
use depthsense_infer::run::validate_net;
use depthsense_infer::NetError;
use depthsense_metrics::{EvalConfig, Metrics, Report, CONDITIONS, REGIONS};
use depthsense_prep::layout::IndexEntry;
use depthsense_progress::{Board, Progress};
use depthsense_train::metrics_log::{read_log, BadLine};
use depthsense_train::trainer::{train, TrainOptions};
use serde::{Deserialize, Serialize};

use super::Stat;

/// How every run of a training experiment (`ablation`, `reduced-data`, `data-scale`) is
/// trained: the same for each variant or grid cell and seed. It holds `train`'s option groups
/// (`depthsense_config::training`) as a run's [`TrainOptions`] takes them, so a run's options
/// are these groups with its own seed, output folder and network; serialised flat into the
/// experiment's options. `schedule.seed` is not used: each run has the seed of its `--seeds`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunSettings {
    /// Prepared data directory.
    pub data: PathBuf,
    /// Model preset (`paper`, `released`, `tiny`, `tiny-wide`) or a model-config JSON file.
    pub preset: String,
    /// `key=value` model-config overrides applied to the preset (an experiment may reserve
    /// fields for itself: the ablation's variants own fusion, attention and head).
    pub set: Vec<String>,
    #[serde(flatten)]
    pub schedule: ScheduleOptions,
    #[serde(flatten)]
    pub loading: LoadingOptions,
    #[serde(flatten)]
    pub validation: ValidationOptions,
    #[serde(flatten)]
    pub hardware: HardwareOptions,
}

impl Default for RunSettings {
    /// The paper's training settings (SPEC §8, `train`'s defaults) on the `paper` preset.
    fn default() -> Self {
        let t = TrainOptions::default();
        Self {
            data: t.data,
            preset: "paper".into(),
            set: vec![],
            schedule: t.schedule,
            loading: t.loading,
            validation: t.validation,
            hardware: t.hardware,
        }
    }
}

impl RunSettings {
    /// The training options of one run stored in `run_dir`: `model` with `seed`, continuing
    /// from the run's last checkpoint when it has one (exact resume).
    pub fn train_options(&self, run_dir: PathBuf, model: &ModelConfig, seed: u64) -> TrainOptions {
        let resume = run_dir
            .join(depthsense_dataset::outputs::LAST_CKPT)
            .exists();
        TrainOptions {
            data: self.data.clone(),
            out: run_dir,
            model: model.clone(),
            schedule: ScheduleOptions {
                seed,
                ..self.schedule.clone()
            },
            loading: self.loading.clone(),
            validation: self.validation.clone(),
            checkpointing: CheckpointOptions {
                resume,
                ..CheckpointOptions::default()
            },
            hardware: self.hardware.clone(),
            ..TrainOptions::default()
        }
    }
}

/// The per-run evaluation file, written after the run's test evaluation.
pub const RUN_EVAL_FILE: &str = "eval.json";

/// What happened to a run in this invocation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RunStatus {
    /// Trained from scratch and evaluated.
    Trained,
    /// Continued from its last checkpoint, then evaluated.
    Resumed,
    /// Training had finished before: only evaluated.
    Evaluated,
    /// Training and evaluation had finished before: read back from eval.json.
    Skipped,
}

/// The headline metrics of one report row.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RowValues {
    pub condition: String,
    pub region: String,
    pub cap_m: f64,
    pub n_images: u64,
    pub n_pixels: u64,
    pub delta1: f64,
    pub rmse: f64,
    pub abs_rel: f64,
    pub mae: f64,
}

impl RowValues {
    /// The Markdown columns of [`RowValues::scenario_md_cells`].
    pub const SCENARIO_MD_COLUMNS: [(&'static str, depthsense_metrics::table::Align); 6] = {
        use depthsense_metrics::table::Align::Right;
        [
            ("images", Right),
            ("RMSE (m)", Right),
            ("ΔRMSE (m)", Right),
            ("MAE (m)", Right),
            ("δ1", Right),
            ("AbsRel", Right),
        ]
    };

    /// The Markdown cells of a scenario of a one-checkpoint experiment (`failure`, `perturb`)
    /// from its combined row: images, RMSE (m), ΔRMSE (m) against `base_rmse`, MAE (m), δ1,
    /// AbsRel — missing values as [`depthsense_metrics::table::MISSING`].
    pub fn scenario_md_cells(row: Option<&RowValues>, base_rmse: Option<f64>) -> [String; 6] {
        use depthsense_metrics::table::{md_num, md_or_missing};
        [
            row.map_or(0, |r| r.n_images).to_string(),
            md_num(row.map(|r| r.rmse), 3),
            md_or_missing(
                row.zip(base_rmse)
                    .map(|(c, b)| super::signed(c.rmse - b, 3)),
            ),
            md_num(row.map(|r| r.mae), 3),
            md_num(row.map(|r| r.delta1), 3),
            md_num(row.map(|r| r.abs_rel), 3),
        ]
    }
}

/// One run (variant × seed): stored as `RUN/eval.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    pub variant: String,
    pub seed: u64,
    pub run_dir: PathBuf,
    /// Training seconds of the invocation(s) that trained it (a resumed run: the last one's,
    /// plus the earlier ones' when recorded).
    pub train_seconds: f64,
    pub eval_seconds: f64,
    /// train + eval.
    pub wall_seconds: f64,
    /// How the training part was done when the record was written.
    pub status: RunStatus,
    pub best_val_rmse: Option<f64>,
    pub test_samples: usize,
    /// Condition × region rows at the largest cap (SPEC §9).
    pub rows: Vec<RowValues>,
    /// The full test report (every cap).
    pub report: Report,
    /// The run's training options (resume decisions compare them).
    pub train_options: TrainOptions,
}

impl RunRecord {
    /// Combined / full image row.
    pub fn headline(&self) -> Option<&RowValues> {
        self.rows
            .iter()
            .find(|r| r.condition == "combined" && r.region == "full")
    }
}

/// Mean ± std over seeds of one condition × region row of a variant.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SummaryRow {
    pub variant: String,
    pub condition: String,
    pub region: String,
    pub cap_m: f64,
    /// Seeds whose run has at least one valid image in this row.
    pub n: usize,
    pub delta1: Option<Stat>,
    pub rmse: Option<Stat>,
    pub abs_rel: Option<Stat>,
    pub mae: Option<Stat>,
}

/// The partition the runs were trained and tested on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PartitionInfo {
    pub method: String,
    pub train_samples: usize,
    pub val_samples: usize,
    pub test_samples: usize,
    pub val_scenes: Vec<String>,
    pub test_scenes: Vec<String>,
}

impl From<&Partition> for PartitionInfo {
    fn from(p: &Partition) -> Self {
        Self {
            method: p.method.clone(),
            train_samples: p.train.len(),
            val_samples: p.val.len(),
            test_samples: p.test.len(),
            val_scenes: p.val_scenes.clone(),
            test_scenes: p.test_scenes.clone(),
        }
    }
}

/// Training options as compared across invocations: without where the data and run live,
/// the device, the thread counts (the loader is thread-count independent), `resume`, `force`,
/// `stop_after` and `checkpoint_every` (an exact resume continues the same computation).
pub fn fingerprint(t: &TrainOptions) -> Result<serde_json::Value, ExperimentError> {
    let mut v = serde_json::to_value(t)?;
    if let Some(m) = v.as_object_mut() {
        for k in [
            "data",
            "out",
            "device",
            "jobs",
            "prefetch",
            "resume",
            "force",
            "stop_after",
            "checkpoint_every",
            "loss_read_every",
        ] {
            m.remove(k);
        }
    }
    Ok(v)
}

/// JSON equality with numbers compared to 1e-12 relative (text round trips).
pub fn same_json(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    use serde_json::Value as V;
    match (a, b) {
        (V::Number(x), V::Number(y)) => match (x.as_f64(), y.as_f64()) {
            (Some(x), Some(y)) => x == y || (x - y).abs() <= 1e-12 * x.abs().max(y.abs()),
            _ => x == y,
        },
        (V::Array(x), V::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(a, b)| same_json(a, b))
        }
        (V::Object(x), V::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, a)| y.get(k).is_some_and(|b| same_json(a, b)))
        }
        _ => a == b,
    }
}

pub fn read_json(path: &Path) -> Result<serde_json::Value, ExperimentError> {
    let text = std::fs::read_to_string(path).map_err(|e| NetError::io(path, e))?;
    let value = serde_json::from_str(&text).map_err(|e| NetError::Parse {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    Ok(value)
}

/// True when RUN/metrics.jsonl records the end of epoch `epochs` and RUN/best.safetensors
/// exists. Also returns the largest "seconds" recorded (training time of the last invocation).
pub fn training_finished(run: &Path, epochs: usize) -> (bool, Option<f64>) {
    // A run killed mid-write may end in half a line: skipped, not an error.
    let Ok(log) = read_log(&run.join(METRICS_FILE), BadLine::Skip) else {
        return (false, None);
    };
    let done = log
        .epoch_ends
        .iter()
        .any(|e| e.epoch == Some(epochs as u64));
    let secs = log
        .epoch_ends
        .iter()
        .filter_map(|e| e.seconds)
        .fold(None, |acc: Option<f64>, s| {
            Some(acc.map_or(s, |p| p.max(s)))
        });
    (done && run.join(BEST_CKPT).exists(), secs)
}

/// The keys in which `stored` and `asked` differ (as [`same_json`] compares), dotted below
/// `prefix` (`model.dropout: 0.5 there, 0.3 asked`), in key order.
pub fn json_differences(
    prefix: &str,
    stored: &serde_json::Value,
    asked: &serde_json::Value,
) -> Vec<String> {
    depthsense_config::refusal::differing_leaves(prefix, Some(stored), Some(asked), &same_json)
        .into_iter()
        .map(|(path, stored, asked)| format!("{path}: {stored} there, {asked} asked"))
        .collect()
}

pub fn row_values(r: &Report) -> Vec<RowValues> {
    let cap = r.config.main_cap();
    let mut out = vec![];
    for cond in CONDITIONS {
        for region in REGIONS {
            if let Some(row) = r.row(cond, region, cap) {
                let m: Metrics = row.metrics;
                out.push(RowValues {
                    condition: cond.into(),
                    region: region.into(),
                    cap_m: cap,
                    n_images: row.n_images,
                    n_pixels: row.n_pixels,
                    delta1: m.delta1,
                    rmse: m.rmse,
                    abs_rel: m.abs_rel,
                    mae: m.mae,
                });
            }
        }
    }
    out
}

pub fn run_bar(mp: &Board, name: &str) -> Progress {
    mp.bar(name)
}

/// Mean ± std over seeds per variant × condition × region (rows without valid images in a
/// run do not count for that run).
pub fn summarise(variants: &[&str], runs: &[RunRecord]) -> Vec<SummaryRow> {
    let mut out = vec![];
    for &v in variants {
        for region in REGIONS {
            for cond in CONDITIONS {
                let rows: Vec<&RowValues> = runs
                    .iter()
                    .filter(|r| r.variant == v)
                    .filter_map(|r| {
                        r.rows
                            .iter()
                            .find(|x| x.condition == cond && x.region == region && x.n_images > 0)
                    })
                    .collect();
                let stat = |f: fn(&RowValues) -> f64| {
                    Stat::of(&rows.iter().map(|r| f(r)).collect::<Vec<_>>())
                };
                out.push(SummaryRow {
                    variant: v.into(),
                    condition: cond.into(),
                    region: region.into(),
                    cap_m: rows.first().map_or(f64::NAN, |r| r.cap_m),
                    n: rows.len(),
                    delta1: stat(|r| r.delta1),
                    rmse: stat(|r| r.rmse),
                    abs_rel: stat(|r| r.abs_rel),
                    mae: stat(|r| r.mae),
                });
            }
        }
    }
    out
}

/// Train (or resume) the run `topts` describes (its `out` is the run folder) and evaluate it
/// on `test`; or read it back when finished. `label` names it in the records ("variant").
pub fn train_and_test(
    label: &str,
    topts: &TrainOptions,
    eval: &EvalConfig,
    ds: &Dataset,
    test: &[IndexEntry],
    device: tch::Device,
    mp: &Board,
) -> Result<(RunRecord, RunStatus), ExperimentError> {
    let run = topts.out.clone();
    let seed = topts.schedule.seed;
    let eval_path = run.join(RUN_EVAL_FILE);
    if let Some(rec) = finished_record(topts, eval)? {
        return Ok((rec, RunStatus::Skipped));
    }
    let name = format!("{label} seed{seed}");
    let pb = run_bar(mp, &name);
    let (status, train_seconds, best_val_rmse) = train_or_reuse(topts, &pb)?;

    // Test evaluation of the checkpoint selected on the validation scenes.
    let t = Instant::now();
    let report = test_best(topts, eval, ds, test, device, &pb)?;
    let eval_seconds = t.elapsed().as_secs_f64();
    let rec = RunRecord {
        variant: label.to_string(),
        seed,
        run_dir: run.clone(),
        train_seconds,
        eval_seconds,
        wall_seconds: train_seconds + eval_seconds,
        status,
        best_val_rmse,
        test_samples: test.len(),
        rows: row_values(&report),
        report,
        train_options: topts.clone(),
    };
    let text = serde_json::to_string_pretty(&rec)?;
    write_atomic(&eval_path, text.as_bytes()).map_err(|e| NetError::io(&eval_path, e))?;
    pb.finish_with_message(format!(
        "test RMSE {:.3} m",
        rec.headline().map_or(f64::NAN, |r| r.rmse)
    ));
    Ok((rec, status))
}

/// The run's finished record (RUN/eval.json) when it exists and was made with these options;
/// refuses a run folder whose record or config.json was made with other options.
fn finished_record(
    topts: &TrainOptions,
    eval: &EvalConfig,
) -> Result<Option<RunRecord>, ExperimentError> {
    let run = &topts.out;
    let fp = fingerprint(topts)?;
    let eval_path = run.join(RUN_EVAL_FILE);
    if eval_path.exists() {
        let v = read_json(&eval_path)?;
        let mut rec: RunRecord = serde_json::from_value(v).map_err(|e| NetError::Parse {
            path: eval_path.to_path_buf(),
            reason: e.to_string(),
        })?;
        let stored_fp = fingerprint(&rec.train_options)?;
        if !same_json(&stored_fp, &fp) || rec.report.config != *eval {
            let mut differences = json_differences("", &stored_fp, &fp);
            differences.extend(json_differences(
                "eval",
                &serde_json::to_value(&rec.report.config)?,
                &serde_json::to_value(eval)?,
            ));
            return Err(ExperimentError::OtherRun {
                run: run.clone(),
                file: RUN_EVAL_FILE,
                differences,
            });
        }
        // A run is recognised by its options, not by where it was trained: one moved here
        // from another --out (a second process's share of the seeds) names its folder now.
        rec.run_dir = run.clone();
        rec.train_options.out = run.clone();
        return Ok(Some(rec));
    }
    let cfg_path = run.join(CONFIG_FILE);
    if cfg_path.exists() {
        let stored = read_json(&cfg_path)?;
        let stored_opts: TrainOptions =
            serde_json::from_value(stored["train"].clone()).map_err(|e| NetError::Parse {
                path: cfg_path.to_path_buf(),
                reason: format!("train: {e}"),
            })?;
        let stored_fp = fingerprint(&stored_opts)?;
        if !same_json(&stored_fp, &fp) {
            return Err(ExperimentError::OtherRun {
                run: run.clone(),
                file: CONFIG_FILE,
                differences: json_differences("", &stored_fp, &fp),
            });
        }
    }
    Ok(None)
}

/// Train (or resume) unless RUN/metrics.jsonl says training ended: (status, training seconds,
/// best validation RMSE).
fn train_or_reuse(
    topts: &TrainOptions,
    pb: &Progress,
) -> Result<(RunStatus, f64, Option<f64>), ExperimentError> {
    let run = &topts.out;
    let cfg_path = run.join(CONFIG_FILE);
    let (finished, earlier_secs) = training_finished(run, topts.schedule.epochs);
    let t = Instant::now();
    let reuse = || {
        let best = checkpoint::read_config(&run.join(BEST_CKPT))
            .ok()
            .and_then(|(_, extra)| extra["train_state"]["best_val_rmse"].as_f64());
        (RunStatus::Evaluated, earlier_secs.unwrap_or(f64::NAN), best)
    };
    Ok(if finished {
        reuse()
    } else {
        let resumed = topts.checkpointing.resume;
        // A run of this experiment (its config matched above) that stopped before its first
        // checkpoint starts over in its own folder.
        let mut topts = topts.clone();
        topts.checkpointing.force = !topts.checkpointing.resume && cfg_path.exists();
        let s = train(&topts, pb)?;
        if s.already_finished.is_some() {
            return Ok(reuse());
        }
        if s.interrupted || s.iterations_done < s.total_iterations {
            return Err(ExperimentError::TrainingStopped {
                run: run.to_path_buf(),
                done: s.iterations_done,
                total: s.total_iterations,
            });
        }
        let status = if resumed {
            RunStatus::Resumed
        } else {
            RunStatus::Trained
        };
        let best = s.best_val_rmse.is_finite().then_some(s.best_val_rmse);
        (status, t.elapsed().as_secs_f64(), best)
    })
}

/// The run's best checkpoint (selected on the validation scenes) on the test scenes.
fn test_best(
    topts: &TrainOptions,
    eval: &EvalConfig,
    ds: &Dataset,
    test: &[IndexEntry],
    device: tch::Device,
    pb: &Progress,
) -> Result<Report, ExperimentError> {
    let best = topts.out.join(BEST_CKPT);
    if !best.exists() {
        return Err(ExperimentError::NoBestCheckpoint(best));
    }
    let loaded = checkpoint::load(&best, device)?;
    loaded
        .net
        .prepare_inference(depthsense_model::precision::InferenceLayout::Fastest);
    let radar = loaded.config.radar_input_for(None)?;
    let load = LoadOptions {
        radar: radar.unwrap_or_default(),
        no_radar: radar.is_none(),
        radar_oracle: topts.loading.radar_oracle,
        ..LoadOptions::default()
    };
    pb.set_length(test.len() as u64);
    pb.set_position(0);
    pb.set_message("test evaluation");
    Ok(validate_net(
        &loaded.net,
        ds,
        test,
        &load,
        eval,
        topts.schedule.batch_size,
        topts.loading.jobs,
        device,
        pb,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// Nested keys are dotted, numbers compare as `same_json` does, a missing key is absent.
    #[test]
    fn json_differences_name_each_key_at_fault() {
        let stored = json!({"lr": 0.001, "model": {"dropout": 0.5, "head": "ordinal"}, "seed": 0});
        let asked = json!({"lr": 0.001 + 1e-16, "model": {"dropout": 0.3, "head": "ordinal"},
                           "seed": 0, "amp": true});
        assert_eq!(
            json_differences("", &stored, &asked),
            [
                "amp: absent there, true asked",
                "model.dropout: 0.5 there, 0.3 asked"
            ]
        );
        assert!(json_differences("", &stored, &stored).is_empty());
        let e = ExperimentError::OtherRun {
            run: "run".into(),
            file: "config.json",
            differences: json_differences("", &stored, &asked),
        };
        assert_eq!(
            e.to_string(),
            "configuration: run: this run was made with other training options (see its \
             config.json) than this experiment asks for (amp: absent there, true asked; \
             model.dropout: 0.5 there, 0.3 asked); use another --out, or delete the run to redo it"
        );
    }
}
