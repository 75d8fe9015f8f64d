//! `depthsense experiment ablation`: the fusion variants of SPEC §6 and the loss ablation of
//! SPEC §10.4, each trained with several seeds on the same prepared data, evaluated on the
//! TEST scenes (the checkpoint is chosen on the validation scenes by the trainer; nothing is
//! selected on test) and reported as mean ± sample std over seeds.
//!
//! ```text
//! OUT/runs/<variant>/seed<k>/           an ordinary training run (config.json, metrics.jsonl, …)
//! OUT/runs/<variant>/seed<k>/eval.json  its test evaluation (written atomically, last)
//! OUT/ablation.md                       tables, verdicts vs rgb, partition, machine, options
//! OUT/ablation.csv                      per-run and mean/std rows
//! OUT/ablation.json                     everything, including each run's full report
//! OUT/ablation.png                      test RMSE and δ1 per variant, mean ± std over seeds
//! ```
//!
//! Resumable: a run with a matching `eval.json` is skipped; a run whose training finished
//! (its metrics.jsonl holds the last epoch) is only evaluated; any other run is (re)started
//! with the trainer's `resume: true`, which continues from its last checkpoint when there is one.

use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Instant;

use depthsense_metrics::{EvalConfig, Metrics, Report, CONDITIONS, REGIONS};
use depthsense_model::{checkpoint, Fusion, HeadKind, ModelConfig};
use depthsense_nuscenes::fsutil::write_atomic;
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};

use super::{signed, Machine, Stat};
use crate::data::{partition, Dataset, LoadOptions, Partition};
use crate::error::TrainError;
use crate::trainer::{
    evaluate_net, radar_input_for, train, TrainOptions, BEST_CKPT, CONFIG_FILE, METRICS_FILE,
};

/// The per-run evaluation file, written after the run's test evaluation.
pub const RUN_EVAL_FILE: &str = "eval.json";
pub const MD_FILE: &str = "ablation.md";
pub const CSV_FILE: &str = "ablation.csv";
pub const JSON_FILE: &str = "ablation.json";
pub const PNG_FILE: &str = "ablation.png";
/// The baseline every other variant is compared with.
pub const BASELINE: &str = "rgb";

/// A network variant: the three config fields it sets (SPEC §6 "Variants", §10.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Variant {
    /// RGB only (fusion none).
    Rgb,
    /// Early fusion: radar channels concatenated to the RGB input, one encoder.
    Early,
    /// Late fusion without the spatial attention module (the released model's form).
    Late,
    /// Late fusion with spatial attention (the paper's model), ordinal head.
    LateSam,
    /// The paper's model with an L1 depth head (loss ablation).
    L1,
    /// The paper's model with an L2 depth head (loss ablation).
    L2,
}

impl Variant {
    pub const ALL: [Variant; 6] = [
        Variant::Rgb,
        Variant::Early,
        Variant::Late,
        Variant::LateSam,
        Variant::L1,
        Variant::L2,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Variant::Rgb => "rgb",
            Variant::Early => "early",
            Variant::Late => "late",
            Variant::LateSam => "late-sam",
            Variant::L1 => "l1",
            Variant::L2 => "l2",
        }
    }

    /// (fusion, attention, head) of the variant.
    pub fn fields(self) -> (Fusion, bool, HeadKind) {
        match self {
            Variant::Rgb => (Fusion::None, false, HeadKind::Ordinal),
            Variant::Early => (Fusion::Early, false, HeadKind::Ordinal),
            Variant::Late => (Fusion::Late, false, HeadKind::Ordinal),
            Variant::LateSam => (Fusion::Late, true, HeadKind::Ordinal),
            Variant::L1 => (Fusion::Late, true, HeadKind::L1),
            Variant::L2 => (Fusion::Late, true, HeadKind::L2),
        }
    }

    /// Set the variant's fields on a config.
    pub fn apply(self, cfg: &mut ModelConfig) {
        let (fusion, attention, head) = self.fields();
        cfg.fusion = fusion;
        cfg.attention = attention;
        cfg.head = head;
    }

    pub fn describe(self) -> &'static str {
        match self {
            Variant::Rgb => "RGB only (no radar)",
            Variant::Early => "early fusion (radar channels on the RGB input)",
            Variant::Late => "late fusion, no attention (released model's form)",
            Variant::LateSam => "late fusion + spatial attention (paper), ordinal head",
            Variant::L1 => "late-sam with an L1 depth head",
            Variant::L2 => "late-sam with an L2 depth head",
        }
    }
}

impl FromStr for Variant {
    type Err = TrainError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.trim().to_ascii_lowercase();
        Variant::ALL
            .into_iter()
            .find(|v| v.name() == s)
            .ok_or_else(|| {
                TrainError::Config(format!(
                    "unknown ablation variant {s:?} (rgb, early, late, late-sam, l1, l2)"
                ))
            })
    }
}

/// Everything an ablation is made of.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AblationOptions {
    /// Prepared data directory.
    pub data: PathBuf,
    /// Output directory (runs/, ablation.{md,csv,json,png}).
    pub out: PathBuf,
    /// Model preset (`paper`, `released`, `tiny`, `tiny-wide`) or a model-config JSON file.
    pub preset: String,
    /// `key=value` model-config overrides applied to the preset before the variant's fields
    /// (they may not set fusion, attention or head: those are the variant's).
    pub set: Vec<String>,
    pub variants: Vec<Variant>,
    pub seeds: Vec<u64>,
    pub epochs: usize,
    pub batch_size: usize,
    pub lr: f64,
    /// auto | cpu | cuda | cuda:N
    pub device: String,
    /// Loader threads (0 = all cores).
    pub jobs: usize,
    /// Validate on at most this many validation samples (None = all).
    pub max_val_samples: Option<usize>,
    /// At most this many batches per epoch (None = all).
    pub max_batches_per_epoch: Option<usize>,
    /// The trainer's `val_every_scene` (partition of data without split lists).
    pub val_every_scene: usize,
    /// Test metrics settings (caps, protocol, aggregation).
    pub eval: EvalConfig,
    /// The invocation, recorded in the outputs (informational).
    pub command_line: Option<String>,
}

impl Default for AblationOptions {
    fn default() -> Self {
        let t = TrainOptions::default();
        Self {
            data: t.data,
            out: PathBuf::from("runs/ablation"),
            preset: "paper".into(),
            set: vec![],
            variants: Variant::ALL.to_vec(),
            seeds: vec![0, 1, 2],
            epochs: t.epochs,
            batch_size: t.batch_size,
            lr: t.lr,
            device: t.device,
            jobs: t.jobs,
            max_val_samples: t.max_val_samples,
            max_batches_per_epoch: t.max_batches_per_epoch,
            val_every_scene: t.val_every_scene,
            eval: EvalConfig::default(),
            command_line: None,
        }
    }
}

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

/// A variant against the baseline on one headline metric (combined, full image).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    pub variant: String,
    pub baseline: String,
    /// "rmse" or "delta1".
    pub metric: String,
    pub mean: f64,
    pub baseline_mean: f64,
    /// mean − baseline mean.
    pub difference: f64,
    /// 100 · difference / baseline mean.
    pub relative_pct: f64,
    /// max(std of the variant, std of the baseline) over seeds; None when either has n < 2.
    pub seed_spread: Option<f64>,
    /// |difference| > seed spread; None when the spread is unknown.
    pub larger_than_spread: Option<bool>,
    pub n: usize,
    pub baseline_n: usize,
    pub text: String,
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

/// Everything an ablation produced (= `ablation.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AblationResult {
    pub options: AblationOptions,
    pub machine: Machine,
    pub partition: PartitionInfo,
    /// The model config of each variant (before the trainer sets the output size).
    pub models: Vec<(String, ModelConfig)>,
    pub runs: Vec<RunRecord>,
    /// What this invocation did to each run, in `runs` order.
    pub status: Vec<RunStatus>,
    pub summary: Vec<SummaryRow>,
    pub verdicts: Vec<Verdict>,
    pub trained: usize,
    pub resumed: usize,
    pub evaluated: usize,
    pub skipped: usize,
    /// Seconds of this invocation.
    pub total_seconds: f64,
}

impl AblationResult {
    /// The summary row of a variant, condition and region.
    pub fn row(&self, variant: &str, condition: &str, region: &str) -> Option<&SummaryRow> {
        self.summary
            .iter()
            .find(|r| r.variant == variant && r.condition == condition && r.region == region)
    }
}

/// The model of a preset name (`tiny-wide` included) or a config JSON file.
fn base_model(spec: &str) -> Result<ModelConfig, TrainError> {
    if spec == "tiny-wide" {
        return crate::demo::demo_model(spec);
    }
    Ok(ModelConfig::resolve(spec)?)
}

/// The model config of each variant (preset → `set` → variant fields).
pub fn variant_models(opts: &AblationOptions) -> Result<Vec<(Variant, ModelConfig)>, TrainError> {
    for s in &opts.set {
        let key = s.split_once('=').map_or(s.as_str(), |(k, _)| k).trim();
        if ["fusion", "attention", "head", "loss"].contains(&key) {
            return Err(TrainError::Config(format!(
                "--set {s}: {key} is what the ablation variants set; choose variants instead"
            )));
        }
    }
    let base = base_model(&opts.preset)?.with_options(&opts.set)?;
    opts.variants
        .iter()
        .map(|&v| {
            let mut c = base.clone();
            v.apply(&mut c);
            c.validate()?;
            Ok((v, c))
        })
        .collect()
}

fn check_options(opts: &AblationOptions) -> Result<(), TrainError> {
    if opts.variants.is_empty() {
        return Err(TrainError::Config("no ablation variants given".into()));
    }
    if opts.seeds.is_empty() {
        return Err(TrainError::Config("no seeds given".into()));
    }
    let dup = |names: Vec<String>| {
        let mut s = names.clone();
        s.sort();
        s.windows(2).find(|w| w[0] == w[1]).map(|w| w[0].clone())
    };
    if let Some(d) = dup(opts.variants.iter().map(|v| v.name().to_string()).collect()) {
        return Err(TrainError::Config(format!("variant {d} given twice")));
    }
    if let Some(d) = dup(opts.seeds.iter().map(|s| s.to_string()).collect()) {
        return Err(TrainError::Config(format!("seed {d} given twice")));
    }
    Ok(())
}

/// Training options as compared across invocations: without where the data and run live,
/// the device, the thread counts (the loader is thread-count independent), `resume`,
/// `stop_after` and `checkpoint_every` (an exact resume continues the same computation).
fn fingerprint(t: &TrainOptions) -> Result<serde_json::Value, TrainError> {
    let mut v = serde_json::to_value(t).map_err(|e| TrainError::Other(e.to_string()))?;
    if let Some(m) = v.as_object_mut() {
        for k in [
            "data",
            "out",
            "device",
            "jobs",
            "prefetch",
            "resume",
            "stop_after",
            "checkpoint_every",
        ] {
            m.remove(k);
        }
    }
    Ok(v)
}

/// JSON equality with numbers compared to 1e-12 relative (text round trips).
fn same_json(a: &serde_json::Value, b: &serde_json::Value) -> bool {
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

fn read_json(path: &Path) -> Result<serde_json::Value, TrainError> {
    let text = std::fs::read_to_string(path).map_err(|e| TrainError::io(path, e))?;
    serde_json::from_str(&text).map_err(|e| TrainError::Parse {
        path: path.display().to_string(),
        reason: e.to_string(),
    })
}

/// True when RUN/metrics.jsonl records the end of epoch `epochs` and RUN/best.safetensors
/// exists. Also returns the largest "seconds" recorded (training time of the last invocation).
fn training_finished(run: &Path, epochs: usize) -> (bool, Option<f64>) {
    let Ok(text) = std::fs::read_to_string(run.join(METRICS_FILE)) else {
        return (false, None);
    };
    let mut done = false;
    let mut secs: Option<f64> = None;
    for l in text.lines() {
        let Ok(v) = serde_json::from_str::<serde_json::Value>(l) else {
            continue;
        };
        if v.get("kind").and_then(|k| k.as_str()) == Some("epoch") {
            if v.get("epoch").and_then(|e| e.as_u64()) == Some(epochs as u64) {
                done = true;
            }
            if let Some(s) = v.get("seconds").and_then(|s| s.as_f64()) {
                secs = Some(secs.map_or(s, |p: f64| p.max(s)));
            }
        }
    }
    (done && run.join(BEST_CKPT).exists(), secs)
}

fn mismatch(run: &Path, file: &str) -> TrainError {
    TrainError::Config(format!(
        "{}: this run was made with other training options (see its {file}) than this \
         ablation asks for; use another --out, or delete the run to redo it",
        run.display()
    ))
}

fn row_values(r: &Report) -> Vec<RowValues> {
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

fn run_bar(mp: &MultiProgress, name: &str) -> ProgressBar {
    let pb = mp.add(ProgressBar::new(0));
    pb.set_style(
        ProgressStyle::with_template(
            "{prefix:>16.bold} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta} {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    pb.set_prefix(name.to_string());
    pb
}

/// Train (or resume) and evaluate one run; or read it back when finished.
#[allow(clippy::too_many_arguments)]
fn one_run(
    opts: &AblationOptions,
    variant: Variant,
    model: &ModelConfig,
    seed: u64,
    ds: &Dataset,
    part: &Partition,
    device: tch::Device,
    mp: &MultiProgress,
) -> Result<(RunRecord, RunStatus), TrainError> {
    let run = opts
        .out
        .join("runs")
        .join(variant.name())
        .join(format!("seed{seed}"));
    let topts = TrainOptions {
        data: opts.data.clone(),
        out: run.clone(),
        model: model.clone(),
        epochs: opts.epochs,
        batch_size: opts.batch_size,
        lr: opts.lr,
        seed,
        device: opts.device.clone(),
        jobs: opts.jobs,
        // Continue an interrupted run from its last checkpoint (exact resume).
        resume: run.join(crate::trainer::LAST_CKPT).exists(),
        max_val_samples: opts.max_val_samples,
        max_batches_per_epoch: opts.max_batches_per_epoch,
        val_every_scene: opts.val_every_scene,
        ..TrainOptions::default()
    };
    let fp = fingerprint(&topts)?;
    let eval_path = run.join(RUN_EVAL_FILE);
    if eval_path.exists() {
        let v = read_json(&eval_path)?;
        let rec: RunRecord = serde_json::from_value(v).map_err(|e| TrainError::Parse {
            path: eval_path.display().to_string(),
            reason: e.to_string(),
        })?;
        if !same_json(&fingerprint(&rec.train_options)?, &fp) || rec.report.config != opts.eval {
            return Err(mismatch(&run, RUN_EVAL_FILE));
        }
        return Ok((rec, RunStatus::Skipped));
    }
    let cfg_path = run.join(CONFIG_FILE);
    if cfg_path.exists() {
        let stored = read_json(&cfg_path)?;
        let stored_opts: TrainOptions =
            serde_json::from_value(stored["train"].clone()).map_err(|e| TrainError::Parse {
                path: cfg_path.display().to_string(),
                reason: format!("train: {e}"),
            })?;
        if !same_json(&fingerprint(&stored_opts)?, &fp) {
            return Err(mismatch(&run, CONFIG_FILE));
        }
    }
    let name = format!("{} seed{seed}", variant.name());
    let pb = run_bar(mp, &name);
    let (finished, earlier_secs) = training_finished(&run, opts.epochs);
    let t = Instant::now();
    let (status, train_seconds, best_val_rmse) = if finished {
        let best = checkpoint::read_config(&run.join(BEST_CKPT))
            .ok()
            .and_then(|(_, extra)| extra["train_state"]["best_val_rmse"].as_f64());
        (RunStatus::Evaluated, earlier_secs.unwrap_or(f64::NAN), best)
    } else {
        let resumed = topts.resume;
        let s = train(&topts, &pb)?;
        if s.interrupted || s.iterations_done < s.total_iterations {
            return Err(TrainError::Other(format!(
                "{}: training stopped at iteration {} of {}",
                run.display(),
                s.iterations_done,
                s.total_iterations
            )));
        }
        let status = if resumed {
            RunStatus::Resumed
        } else {
            RunStatus::Trained
        };
        let best = s.best_val_rmse.is_finite().then_some(s.best_val_rmse);
        (status, t.elapsed().as_secs_f64(), best)
    };

    // Test evaluation of the checkpoint selected on the validation scenes.
    let t = Instant::now();
    let best = run.join(BEST_CKPT);
    if !best.exists() {
        return Err(TrainError::Data(format!(
            "{}: missing — no epoch improved the validation RMSE (non-finite?)",
            best.display()
        )));
    }
    let loaded = checkpoint::load(&best, device)?;
    let radar = radar_input_for(&loaded.config, None)?;
    let load = LoadOptions {
        radar: radar.unwrap_or_default(),
        no_radar: radar.is_none(),
        ..LoadOptions::default()
    };
    pb.set_length(part.test.len() as u64);
    pb.set_position(0);
    pb.set_message("test evaluation");
    let report = evaluate_net(
        &loaded.net,
        ds,
        &part.test,
        &load,
        &opts.eval,
        opts.batch_size,
        opts.jobs,
        device,
        &pb,
        |_, _| Ok(()),
    )?;
    let eval_seconds = t.elapsed().as_secs_f64();
    let rec = RunRecord {
        variant: variant.name().into(),
        seed,
        run_dir: run.clone(),
        train_seconds,
        eval_seconds,
        wall_seconds: train_seconds + eval_seconds,
        status,
        best_val_rmse,
        test_samples: part.test.len(),
        rows: row_values(&report),
        report,
        train_options: topts,
    };
    let text = serde_json::to_string_pretty(&rec).map_err(|e| TrainError::Other(e.to_string()))?;
    write_atomic(&eval_path, text.as_bytes()).map_err(|e| TrainError::io(&eval_path, e))?;
    pb.finish_with_message(format!(
        "test RMSE {:.3} m",
        rec.headline().map_or(f64::NAN, |r| r.rmse)
    ));
    Ok((rec, status))
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

/// The verdict rule: the difference of the two means is "larger than the seed spread" when
/// |mean(variant) − mean(baseline)| > max(std(variant), std(baseline)) (sample stds over
/// seeds); undecided when either variant has fewer than 2 seeds.
pub fn verdict(variant: &str, baseline: &str, metric: &str, v: &Stat, b: &Stat) -> Verdict {
    let diff = v.mean - b.mean;
    let rel = 100.0 * diff / b.mean;
    let spread = match (v.std, b.std) {
        (Some(x), Some(y)) => Some(x.max(y)),
        _ => None,
    };
    let larger = spread.map(|s| diff.abs() > s);
    let (label, unit, prec) = match metric {
        "rmse" => ("RMSE", " m", 3),
        _ => ("δ1", "", 3),
    };
    let spread_txt = spread.map_or("unknown (n < 2)".to_string(), |s| {
        format!("±{s:.prec$}{unit}")
    });
    let conclusion = match larger {
        Some(true) => "larger than the seed spread",
        Some(false) => "NOT larger than the seed spread",
        None => "no verdict",
    };
    let text = format!(
        "{variant} vs {baseline}: {label} {} % (mean {:.prec$}{unit} vs {:.prec$}{unit}), \
         difference {}{unit} vs seed spread {spread_txt} (n = {} / {}) → {conclusion}",
        signed(rel, 1),
        v.mean,
        b.mean,
        signed(diff, prec),
        v.n,
        b.n
    );
    Verdict {
        variant: variant.into(),
        baseline: baseline.into(),
        metric: metric.into(),
        mean: v.mean,
        baseline_mean: b.mean,
        difference: diff,
        relative_pct: rel,
        seed_spread: spread,
        larger_than_spread: larger,
        n: v.n,
        baseline_n: b.n,
        text,
    }
}

fn verdicts(variants: &[&str], summary: &[SummaryRow]) -> Vec<Verdict> {
    let get = |v: &str| {
        summary
            .iter()
            .find(|r| r.variant == v && r.condition == "combined" && r.region == "full")
    };
    let Some(base) = get(BASELINE) else {
        return vec![];
    };
    let mut out = vec![];
    for &v in variants.iter().filter(|v| **v != BASELINE) {
        let Some(row) = get(v) else { continue };
        for (metric, a, b) in [
            ("rmse", row.rmse, base.rmse),
            ("delta1", row.delta1, base.delta1),
        ] {
            if let (Some(a), Some(b)) = (a, b) {
                out.push(verdict(v, BASELINE, metric, &a, &b));
            }
        }
    }
    out
}

/// Run the ablation: every variant × seed, test evaluation, tables and chart in `opts.out`.
/// `mp` hosts one progress bar per run (pass a hidden one in tests).
pub fn run_ablation(
    opts: &AblationOptions,
    mp: &MultiProgress,
) -> Result<AblationResult, TrainError> {
    let t0 = Instant::now();
    check_options(opts)?;
    let models = variant_models(opts)?;
    let device = depthsense_model::device::parse_device(&opts.device)?;
    let ds = Dataset::open(&opts.data)?;
    let part = partition(&ds, opts.val_every_scene)?;
    if part.test.is_empty() {
        return Err(TrainError::Data(format!(
            "{}: no test samples ({}): the ablation reports on the test scenes and never on \
             the validation scenes the checkpoints are selected on; prepare the data with a \
             test split (or without split lists, so that scenes are held out for test)",
            opts.data.display(),
            part.method
        )));
    }
    std::fs::create_dir_all(&opts.out).map_err(|e| TrainError::io(&opts.out, e))?;
    let total = models.len() * opts.seeds.len();
    let overall = run_bar(mp, "ablation runs");
    overall.set_length(total as u64);
    let mut runs = vec![];
    let mut status = vec![];
    for (variant, model) in &models {
        for &seed in &opts.seeds {
            overall.set_message(format!("{} seed{seed}", variant.name()));
            let (rec, st) = one_run(opts, *variant, model, seed, &ds, &part, device, mp)?;
            runs.push(rec);
            status.push(st);
            overall.inc(1);
        }
    }
    overall.finish_with_message("done");
    let names: Vec<&str> = models.iter().map(|(v, _)| v.name()).collect();
    let summary = summarise(&names, &runs);
    let verdicts = verdicts(&names, &summary);
    let count = |s: RunStatus| status.iter().filter(|x| **x == s).count();
    let result = AblationResult {
        options: opts.clone(),
        machine: Machine::describe(device),
        partition: PartitionInfo::from(&part),
        models: models
            .iter()
            .map(|(v, c)| (v.name().to_string(), c.clone()))
            .collect(),
        trained: count(RunStatus::Trained),
        resumed: count(RunStatus::Resumed),
        evaluated: count(RunStatus::Evaluated),
        skipped: count(RunStatus::Skipped),
        runs,
        status,
        summary,
        verdicts,
        total_seconds: t0.elapsed().as_secs_f64(),
    };
    write_outputs(&opts.out, &result)?;
    Ok(result)
}

fn save(path: &Path, bytes: &[u8]) -> Result<(), TrainError> {
    write_atomic(path, bytes).map_err(|e| TrainError::io(path, e))
}

fn write_outputs(dir: &Path, r: &AblationResult) -> Result<(), TrainError> {
    let json = serde_json::to_string_pretty(r).map_err(|e| TrainError::Other(e.to_string()))?;
    save(&dir.join(JSON_FILE), json.as_bytes())?;
    save(&dir.join(CSV_FILE), csv(r).as_bytes())?;
    save(&dir.join(MD_FILE), markdown(r).as_bytes())?;
    save(&dir.join(PNG_FILE), &chart(r)?)?;
    Ok(())
}

fn headline_stats(r: &AblationResult) -> (Vec<&str>, [Vec<f64>; 4]) {
    let names: Vec<&str> = r.models.iter().map(|(n, _)| n.as_str()).collect();
    let mut cols: [Vec<f64>; 4] = Default::default();
    for n in &names {
        let row = r.row(n, "combined", "full");
        let (rm, rs) = row.and_then(|x| x.rmse).map_or((f64::NAN, f64::NAN), |s| {
            (s.mean, s.std.unwrap_or(f64::NAN))
        });
        let (dm, dsd) = row
            .and_then(|x| x.delta1)
            .map_or((f64::NAN, f64::NAN), |s| {
                (s.mean, s.std.unwrap_or(f64::NAN))
            });
        cols[0].push(rm);
        cols[1].push(rs);
        cols[2].push(dm);
        cols[3].push(dsd);
    }
    (names, cols)
}

fn chart(r: &AblationResult) -> Result<Vec<u8>, TrainError> {
    let (names, [rm, rs, dm, dsd]) = headline_stats(r);
    let n = r.options.seeds.len();
    let t1 = format!("test RMSE (m), mean ± std over {n} seed(s)");
    let t2 = format!("test δ1, mean ± std over {n} seed(s)");
    crate::plot::bar_charts_png(&[
        crate::plot::BarPanel {
            title: &t1,
            labels: &names,
            means: &rm,
            stds: &rs,
            y_label: "RMSE (m)",
        },
        crate::plot::BarPanel {
            title: &t2,
            labels: &names,
            means: &dm,
            stds: &dsd,
            y_label: "δ1",
        },
    ])
}

fn opt_f(x: Option<f64>, prec: usize) -> String {
    x.filter(|v| v.is_finite())
        .map_or(String::new(), |v| format!("{v:.prec$}"))
}

fn csv(r: &AblationResult) -> String {
    let mut s = String::from(
        "kind,variant,seed,condition,region,cap_m,n,n_images,delta1,delta1_std,rmse_m,rmse_std_m,\
         abs_rel,abs_rel_std,mae_m,mae_std_m,train_s,eval_s,wall_s\n",
    );
    for run in &r.runs {
        for x in &run.rows {
            s.push_str(&format!(
                "run,{},{},{},{},{},1,{},{:.6},,{:.6},,{:.6},,{:.6},,{:.2},{:.2},{:.2}\n",
                run.variant,
                run.seed,
                x.condition,
                x.region,
                x.cap_m,
                x.n_images,
                x.delta1,
                x.rmse,
                x.abs_rel,
                x.mae,
                run.train_seconds,
                run.eval_seconds,
                run.wall_seconds
            ));
        }
    }
    for x in &r.summary {
        let st = |s: &Option<Stat>| (opt_f(s.map(|s| s.mean), 6), opt_f(s.and_then(|s| s.std), 6));
        let (d, ds) = st(&x.delta1);
        let (rm, rs) = st(&x.rmse);
        let (a, as_) = st(&x.abs_rel);
        let (m, ms) = st(&x.mae);
        s.push_str(&format!(
            "mean,{},,{},{},{},{},,{d},{ds},{rm},{rs},{a},{as_},{m},{ms},,,\n",
            x.variant,
            x.condition,
            x.region,
            opt_f(Some(x.cap_m), 0),
            x.n
        ));
    }
    s
}

fn md_stat(s: &Option<Stat>) -> String {
    s.map_or("–".into(), |s| s.fmt(3))
}

fn markdown(r: &AblationResult) -> String {
    let o = &r.options;
    let seeds: Vec<String> = o.seeds.iter().map(|s| s.to_string()).collect();
    let mut md = String::from("# Ablation: fusion variants and loss (SPEC §6, §10.1, §10.4)\n\n");
    md.push_str(&format!(
        "Each variant trained with seeds {} (n = {} per variant) on the same data; each run's \
         `best.safetensors` (lowest RMSE on the validation scenes) evaluated on the **test** \
         scenes. Values: mean ± sample std over seeds (divisor n − 1; \"–\" when n < 2).\n\n",
        seeds.join(", "),
        seeds.len()
    ));
    md.push_str("| variant | fusion | attention | head | description |\n|---|---|---|---|---|\n");
    for (name, c) in &r.models {
        let desc = Variant::from_str(name).map_or("", |v| v.describe());
        md.push_str(&format!(
            "| {name} | {:?} | {} | {:?} | {desc} |\n",
            c.fusion, c.attention, c.head
        ));
    }
    md.push('\n');

    if !r.verdicts.is_empty() {
        md.push_str("## Verdicts vs rgb (combined, full image)\n\n");
        md.push_str(
            "Rule: a difference of means counts as *larger than the seed spread* when \
             |mean(variant) − mean(rgb)| > max(std(variant), std(rgb)), the larger of the two \
             variants' sample stds over seeds; with fewer than 2 seeds on either side there is \
             no verdict. This is a rough screen, not a significance test.\n\n",
        );
        for v in &r.verdicts {
            md.push_str(&format!("- {}\n", v.text));
        }
        md.push('\n');
    }

    let cap = r
        .summary
        .iter()
        .map(|x| x.cap_m)
        .find(|c| c.is_finite())
        .unwrap_or(o.eval.main_cap());
    for (region, title) in [("full", "Full image"), ("lowheight", "Low-height region")] {
        md.push_str(&format!(
            "## {title}, cap {cap:.0} m (test scenes)\n\n\
             | variant | condition | n | δ1 | RMSE (m) | AbsRel | MAE (m) |\n\
             |---|---|---:|---:|---:|---:|---:|\n"
        ));
        for x in r.summary.iter().filter(|x| x.region == region) {
            md.push_str(&format!(
                "| {} | {} | {} | {} | {} | {} | {} |\n",
                x.variant,
                x.condition,
                x.n,
                md_stat(&x.delta1),
                md_stat(&x.rmse),
                md_stat(&x.abs_rel),
                md_stat(&x.mae)
            ));
        }
        md.push('\n');
    }

    md.push_str(
        "## Per run (combined, full image)\n\n\
         | variant | seed | δ1 | RMSE (m) | AbsRel | MAE (m) | best val RMSE (m) | train s | eval s | this invocation |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|---|\n",
    );
    for (run, st) in r.runs.iter().zip(&r.status) {
        let h = run.headline();
        let f = |g: fn(&RowValues) -> f64| h.map_or("–".into(), |x| format!("{:.3}", g(x)));
        md.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {:.1} | {:.1} | {} |\n",
            run.variant,
            run.seed,
            f(|x| x.delta1),
            f(|x| x.rmse),
            f(|x| x.abs_rel),
            f(|x| x.mae),
            opt_f(run.best_val_rmse, 3),
            run.train_seconds,
            run.eval_seconds,
            serde_json::to_value(st)
                .ok()
                .and_then(|v| v.as_str().map(String::from))
                .unwrap_or_default()
        ));
    }
    md.push('\n');

    let p = &r.partition;
    md.push_str(&format!(
        "## Setup\n\n\
         - Partition: {} — {} train, {} validation, {} test samples.\n\
         - Validation scenes (checkpoint selection): {}\n\
         - Test scenes (reported above; never used for selection): {}\n\
         - Model preset `{}`{}; {} epochs, batch {}, lr {}, max batches/epoch {}, max validation samples {}.\n\
         - Metrics: caps {:?} m, protocol {:?}, aggregation {:?}, prediction clipped to [{}, {}] m (SPEC §9).\n\
         - Machine: {}.\n\
         - This invocation: {} trained, {} resumed, {} evaluated only, {} skipped (finished before); {:.1} s.\n",
        p.method,
        p.train_samples,
        p.val_samples,
        p.test_samples,
        p.val_scenes.join(", "),
        p.test_scenes.join(", "),
        o.preset,
        if o.set.is_empty() {
            String::new()
        } else {
            format!(" with `--set {}`", o.set.join(" --set "))
        },
        o.epochs,
        o.batch_size,
        o.lr,
        o.max_batches_per_epoch
            .map_or("all".to_string(), |m| m.to_string()),
        o.max_val_samples.map_or("all".to_string(), |m| m.to_string()),
        o.eval.caps_m,
        o.eval.protocol,
        o.eval.aggregate,
        o.eval.clip_min_m,
        o.eval.clip_max_m,
        r.machine.line(),
        r.trained,
        r.resumed,
        r.evaluated,
        r.skipped,
        r.total_seconds
    ));
    if let Some(c) = &o.command_line {
        md.push_str(&format!("- Command: `{c}`\n"));
    }
    md.push_str(&format!(
        "\nFiles: `{CSV_FILE}` (per-run and mean rows), `{JSON_FILE}` (everything, with each \
         run's full report), `{PNG_FILE}` (test RMSE and δ1 per variant, error bars ± 1 std), \
         `runs/<variant>/seed<k>/` (training runs with their `{RUN_EVAL_FILE}`).\n"
    ));
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variants_parse_and_set_their_fields() {
        for v in Variant::ALL {
            assert_eq!(Variant::from_str(v.name()).unwrap(), v);
        }
        assert!(Variant::from_str("sam").is_err());
        let mut c = ModelConfig::tiny();
        Variant::Rgb.apply(&mut c);
        assert_eq!((c.fusion, c.attention), (Fusion::None, false));
        Variant::L2.apply(&mut c);
        assert_eq!(
            (c.fusion, c.attention, c.head),
            (Fusion::Late, true, HeadKind::L2)
        );
        let opts = AblationOptions {
            preset: "tiny".into(),
            set: vec!["head=l1".into()],
            ..AblationOptions::default()
        };
        assert!(
            variant_models(&opts).is_err(),
            "--set head is the variant's"
        );
    }

    #[test]
    fn verdict_compares_the_difference_with_the_larger_std() {
        let rgb = Stat {
            mean: 5.0,
            std: Some(0.1),
            n: 3,
        };
        let sam = Stat {
            mean: 4.5,
            std: Some(0.3),
            n: 3,
        };
        let v = verdict("late-sam", "rgb", "rmse", &sam, &rgb);
        assert!((v.difference + 0.5).abs() < 1e-12);
        assert!((v.relative_pct + 10.0).abs() < 1e-9);
        assert_eq!(v.seed_spread, Some(0.3));
        assert_eq!(v.larger_than_spread, Some(true));
        assert!(v.text.contains("RMSE −10.0 %"), "{}", v.text);
        assert!(
            v.text.ends_with("→ larger than the seed spread"),
            "{}",
            v.text
        );
        let close = Stat { mean: 4.8, ..sam };
        let v = verdict("late", "rgb", "rmse", &close, &rgb);
        assert_eq!(v.larger_than_spread, Some(false));
        assert!(v.text.contains("NOT larger"));
        let single = Stat {
            std: None,
            n: 1,
            ..sam
        };
        assert_eq!(
            verdict("l1", "rgb", "rmse", &single, &rgb).larger_than_spread,
            None
        );
    }

    #[test]
    fn json_comparison_tolerates_float_text_round_trips() {
        let a = serde_json::json!({"lr": 0.001, "x": [1, 2.5]});
        let b: serde_json::Value = serde_json::from_str(&a.to_string()).unwrap();
        assert!(same_json(&a, &b));
        assert!(!same_json(
            &a,
            &serde_json::json!({"lr": 0.002, "x": [1, 2.5]})
        ));
    }
}
