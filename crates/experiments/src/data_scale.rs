//! Radar's margin against training-set size at matched compute (`experiment data-scale`):
//! every arm (an ablation variant, optionally with model options: `late-sam+radar-skip=8`)
//! trains on N = each size of distinct training samples — nested subsets, the same for every
//! seed and arm (`train --train-subset`) — for the **same number of iterations** at every N
//! (`train --epoch-iterations`: validations every I/E iterations, E = `--epochs`), is selected
//! on the same validation scenes and tested on the same test scenes. Per N the first arm is
//! the baseline and every other arm is compared with it, paired over seeds
//! ([`crate::ablation::verdict`]). Extra arms (`--at-largest`) train at the largest N only.
//!
//! ```text
//! OUT/runs/n<N>/<arm>/seed<k>/   an ordinary training run (+ eval.json, see `runner`)
//! OUT/data_scale.{md,csv,json,png}
//! ```

use std::path::PathBuf;
use std::str::FromStr;
use std::time::Instant;

use crate::{ExperimentError, SpecRefusal};
use depthsense_config::ModelConfig;
use depthsense_dataset::{partition, Dataset};
use depthsense_metrics::doc::Doc;
use depthsense_metrics::table::{csv_quoted, csv_row, Align, MdTable};
use depthsense_metrics::EvalConfig;
use depthsense_progress::Board;
use serde::{Deserialize, Serialize};

use super::ablation::{verdict, Verdict};
use super::runner::{run_bar, train_and_test, PartitionInfo, RunRecord, RunSettings};
use super::{Machine, Stat};
use depthsense_config::variant::Variant;

pub const MD_FILE: &str = "data_scale.md";
pub const CSV_FILE: &str = "data_scale.csv";
pub const JSON_FILE: &str = "data_scale.json";
pub const PNG_FILE: &str = "data_scale.png";

/// One arm of the comparison: an ablation variant and model options on top of it
/// (`late-sam+radar-skip=8`: the options joined by `+`, each a `--set` key=value), and the
/// word `oracle` for the oracle radar (`late-sam+oracle`, `train --radar-oracle`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Arm {
    /// The text it was given, its name in the tables and its run folder.
    pub label: String,
    pub variant: Variant,
    pub set: Vec<String>,
    /// Train, validate and test on the oracle radar. Absent from the JSON when false.
    #[serde(default, skip_serializing_if = "depthsense_data::is_default")]
    pub radar_oracle: bool,
}

/// The arm word for the oracle radar.
pub const ORACLE_WORD: &str = "oracle";

impl FromStr for Arm {
    type Err = ExperimentError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let label = s.trim().to_string();
        let mut parts = label.split('+');
        let variant: Variant = parts.next().unwrap_or_default().parse()?;
        let mut set: Vec<String> = parts.map(|p| p.trim().to_string()).collect();
        let before = set.len();
        set.retain(|p| p != ORACLE_WORD);
        let radar_oracle = set.len() < before;
        if radar_oracle && matches!(variant, Variant::Rgb | Variant::LateSamMer) {
            return Err(SpecRefusal::OracleWithoutRadar { arm: label }.into());
        }
        for kv in &set {
            let key = kv.split_once('=').map_or(kv.as_str(), |(k, _)| k).trim();
            if !kv.contains('=') || ["fusion", "attention", "head", "loss"].contains(&key) {
                return Err(SpecRefusal::ArmSetting {
                    arm: label,
                    setting: kv.clone(),
                }
                .into());
            }
        }
        Ok(Arm {
            label,
            variant,
            set,
            radar_oracle,
        })
    }
}

impl Arm {
    /// The arm's network: preset → shared `set` → variant fields → the arm's own options.
    pub fn model(&self, base: &ModelConfig) -> Result<ModelConfig, ExperimentError> {
        let mut c = base.clone();
        self.variant.apply(&mut c);
        let c = c.with_options(&self.set)?;
        c.validate()?;
        Ok(c)
    }
}

/// Everything a data-scale experiment is made of.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DataScaleOptions {
    /// Data, preset, shared `set` and training settings; `epochs` = validations per run.
    #[serde(flatten)]
    pub run: RunSettings,
    pub out: PathBuf,
    /// Training-set sizes N (distinct training samples).
    pub sizes: Vec<usize>,
    /// The arms trained at every N; the first is the baseline of the paired comparisons.
    pub arms: Vec<Arm>,
    /// Arms trained at the largest N only (e.g. `late-sam+radar-skip=8`, `late-sam-mer`).
    pub at_largest: Vec<Arm>,
    pub seeds: Vec<u64>,
    /// Training iterations of every run; None: the fewest that show the largest N each image
    /// once (⌈N_max / batch⌉), rounded up to a multiple of `epochs`.
    pub iterations: Option<u64>,
    pub eval: EvalConfig,
    pub command_line: Option<String>,
}

/// One (N, arm) cell: test metrics over seeds and the comparison with the baseline arm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScaleRow {
    pub train_samples: usize,
    pub arm: String,
    /// Passes over the N training samples each run makes (iterations × batch / N).
    pub passes: f64,
    pub rmse: Option<Stat>,
    pub mae: Option<Stat>,
    pub abs_rel: Option<Stat>,
    pub delta1: Option<Stat>,
    /// Radar's margin: the baseline's test RMSE minus this arm's, per seed (m; positive =
    /// this arm is better).
    pub margin_m: Option<Stat>,
    /// The same per seed as a percentage of the baseline's RMSE.
    pub margin_pct: Option<Stat>,
    /// Standard error of the seed mean of `margin_m` (m; the table's "±").
    #[serde(default)]
    pub margin_se_m: Option<f64>,
    /// Standard error of the seed mean of `margin_pct` (%; the table's "±").
    #[serde(default)]
    pub margin_se_pct: Option<f64>,
    /// Paired t of the margin (positive = this arm is better; the table's "t (margin)").
    #[serde(default)]
    pub margin_t: Option<f64>,
    /// The paired test of the RMSE against the baseline (None for the baseline itself).
    pub vs_baseline: Option<Verdict>,
}

/// Everything the experiment produced (= data_scale.json).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DataScaleResult {
    pub options: DataScaleOptions,
    pub machine: Machine,
    /// The full partition (before the subsets).
    pub partition: PartitionInfo,
    /// Iterations of every run and iterations between validations.
    pub iterations: u64,
    pub epoch_iterations: u64,
    pub runs: Vec<RunRecord>,
    pub rows: Vec<ScaleRow>,
    /// One sentence: how the margin changed from the smallest to the largest N.
    pub trend: Option<String>,
    pub total_seconds: f64,
}

impl DataScaleResult {
    pub fn row(&self, n: usize, arm: &str) -> Option<&ScaleRow> {
        self.rows
            .iter()
            .find(|r| r.train_samples == n && r.arm == arm)
    }
}

fn check(opts: &DataScaleOptions, available: usize) -> Result<(), SpecRefusal> {
    for (empty, what) in [
        (opts.sizes.is_empty(), "training-set sizes"),
        (opts.arms.is_empty(), "arms"),
        (opts.seeds.is_empty(), "seeds"),
    ] {
        if empty {
            return Err(SpecRefusal::NothingGiven(what));
        }
    }
    if opts.sizes.contains(&0) {
        return Err(SpecRefusal::ZeroSize);
    }
    if opts.run.schedule.epoch_iterations.is_some() {
        return Err(SpecRefusal::EpochIterationsGiven);
    }
    let mut labels: Vec<&str> = opts
        .arms
        .iter()
        .chain(&opts.at_largest)
        .map(|a| a.label.as_str())
        .collect();
    labels.sort_unstable();
    if let Some(w) = labels.windows(2).find(|w| w[0] == w[1]) {
        return Err(SpecRefusal::GivenTwice {
            what: "arm",
            item: w[0].to_string(),
        });
    }
    let largest = opts.sizes.iter().max().copied().unwrap_or(0);
    if largest > available {
        return Err(SpecRefusal::SizeExceedsData {
            size: largest,
            data: opts.run.data.clone(),
            available,
        });
    }
    if let Some(i) = opts.iterations {
        if (i as u128) * (opts.run.schedule.batch_size as u128) < largest as u128 {
            return Err(SpecRefusal::TooFewIterations {
                iterations: i,
                batch: opts.run.schedule.batch_size,
                largest,
                needed: largest.div_ceil(opts.run.schedule.batch_size.max(1)),
            });
        }
    }
    Ok(())
}

/// (iterations, iterations per epoch): the requested or the fewest that show the largest N
/// every image once, rounded up to a multiple of the epochs.
pub fn schedule(opts: &DataScaleOptions) -> (u64, u64) {
    let largest = opts.sizes.iter().max().copied().unwrap_or(1) as u64;
    let batch = opts.run.schedule.batch_size.max(1) as u64;
    let epochs = opts.run.schedule.epochs.max(1) as u64;
    let wanted = opts.iterations.unwrap_or(largest.div_ceil(batch)).max(1);
    let per_epoch = wanted.div_ceil(epochs);
    (per_epoch * epochs, per_epoch)
}

fn run_dir(out: &std::path::Path, n: usize, arm: &Arm, seed: u64) -> PathBuf {
    out.join("runs")
        .join(format!("n{n}"))
        .join(arm.label.replace(['+', '=', ',', '/'], "_"))
        .join(format!("seed{seed}"))
}

/// Train every size × arm × seed (and the extra arms at the largest size), test on the test
/// scenes, write the tables and the chart. Resumable like the ablation.
pub fn run_data_scale(
    opts: &DataScaleOptions,
    mp: &Board,
) -> Result<DataScaleResult, ExperimentError> {
    let t0 = Instant::now();
    let device = depthsense_model::device::parse_device(&opts.run.hardware.device.name)?;
    let ds = Dataset::open(&opts.run.data)?;
    let part = partition(&ds, opts.run.validation.val_every_scene)?;
    check(opts, part.train.len())?;
    if part.test.is_empty() {
        return Err(ExperimentError::NoTestSamples {
            data: opts.run.data.clone(),
            method: part.method.to_string(),
            experiment: "data-scale",
        });
    }
    let base = super::ablation::base_model(&opts.run.preset)?.with_options(&opts.run.set)?;
    let (iterations, per_epoch) = schedule(opts);
    let plan = plan_runs(opts, &base)?;
    let _writing = depthsense_base::lock::OutputLock::exclusive(
        &opts.out,
        "depthsense experiment data-scale",
    )?;
    let overall = run_bar(mp, "data-scale runs");
    overall.set_length(plan.len() as u64);
    overall.println(format!(
        "{} runs of {iterations} iterations (validated every {per_epoch}) into {}",
        plan.len(),
        opts.out.display()
    ));
    let mut runs = vec![];
    for (n, arm, seed, model) in plan {
        overall.set_message(format!("n{n} {} seed{seed}", arm.label));
        let mut t = opts
            .run
            .train_options(run_dir(&opts.out, n, arm, seed), &model, seed);
        t.loading.train_subset = Some(n);
        t.schedule.epoch_iterations = Some(per_epoch);
        t.loading.radar_oracle = arm.radar_oracle;
        let (rec, _) = train_and_test(&arm.label, &t, &opts.eval, &ds, &part.test, device, mp)?;
        runs.push(rec);
        overall.inc(1);
    }
    overall.finish_with_message("done");
    let rows = summarise(opts, iterations, &runs);
    let result = DataScaleResult {
        options: opts.clone(),
        machine: Machine::describe(device),
        partition: PartitionInfo::from(&part),
        iterations,
        epoch_iterations: per_epoch,
        trend: trend(opts, &rows),
        rows,
        runs,
        total_seconds: t0.elapsed().as_secs_f64(),
    };
    write_outputs(&result)?;
    Ok(result)
}

/// Every run to train, seed after seed: (training-set size N, arm, seed, network) for each size
/// × arm, then the extra arms at the largest size.
fn plan_runs<'a>(
    opts: &'a DataScaleOptions,
    base: &ModelConfig,
) -> Result<Vec<(usize, &'a Arm, u64, ModelConfig)>, ExperimentError> {
    let mut plan: Vec<(usize, &Arm, u64, ModelConfig)> = vec![];
    let largest = opts.sizes.iter().max().copied().unwrap_or(0);
    for &seed in &opts.seeds {
        for &n in &opts.sizes {
            for arm in &opts.arms {
                plan.push((n, arm, seed, arm.model(base)?));
            }
        }
        for arm in &opts.at_largest {
            plan.push((largest, arm, seed, arm.model(base)?));
        }
    }
    Ok(plan)
}

/// The training-set size of a run (its `train_subset`).
fn size_of(r: &RunRecord) -> usize {
    r.train_options.loading.train_subset.unwrap_or(0)
}

/// (seed, arm RMSE, baseline RMSE) of the seeds both ran at size `n`.
fn pairs(runs: &[RunRecord], n: usize, arm: &str, baseline: &str) -> Vec<(u64, f64, f64)> {
    let rmse = |name: &str, seed: u64| {
        runs.iter()
            .find(|r| size_of(r) == n && r.variant == name && r.seed == seed)
            .and_then(|r| r.headline())
            .map(|h| h.rmse)
    };
    runs.iter()
        .filter(|r| size_of(r) == n && r.variant == arm)
        .filter_map(|r| Some((r.seed, rmse(arm, r.seed)?, rmse(baseline, r.seed)?)))
        .collect()
}

fn summarise(opts: &DataScaleOptions, iterations: u64, runs: &[RunRecord]) -> Vec<ScaleRow> {
    let mut sizes = opts.sizes.clone();
    sizes.sort_unstable();
    sizes.dedup();
    let mut out = vec![];
    for &n in &sizes {
        for arm in opts.arms.iter().chain(&opts.at_largest) {
            if let Some(row) = scale_row(opts, iterations, runs, n, arm) {
                out.push(row);
            }
        }
    }
    out
}

/// The (N, arm) cell of the table: the arm's test metrics over its seeds at size `n` and its
/// margin over the baseline (the first arm); `None` when no run of the cell was tested.
fn scale_row(
    opts: &DataScaleOptions,
    iterations: u64,
    runs: &[RunRecord],
    n: usize,
    arm: &Arm,
) -> Option<ScaleRow> {
    let baseline = opts.arms[0].label.as_str();
    let heads: Vec<_> = runs
        .iter()
        .filter(|r| size_of(r) == n && r.variant == arm.label)
        .filter_map(|r| r.headline())
        .collect();
    if heads.is_empty() {
        return None;
    }
    let stat = |f: fn(&super::runner::RowValues) -> f64| {
        Stat::of(&heads.iter().map(|h| f(h)).collect::<Vec<_>>())
    };
    let p = pairs(runs, n, &arm.label, baseline);
    let is_base = arm.label == baseline;
    let rmse = stat(|h| h.rmse);
    let vs_baseline = baseline_verdict(runs, n, &arm.label, baseline, rmse, &p);
    let (margin_m, margin_pct) = margins(&p, is_base);
    let margin_t = vs_baseline
        .as_ref()
        .and_then(|v| v.paired.as_ref())
        .and_then(|p| p.t)
        .map(|t| -t);
    Some(ScaleRow {
        train_samples: n,
        arm: arm.label.clone(),
        passes: iterations as f64 * opts.run.schedule.batch_size as f64 / n as f64,
        rmse,
        mae: stat(|h| h.mae),
        abs_rel: stat(|h| h.abs_rel),
        delta1: stat(|h| h.delta1),
        margin_se_m: margin_m.as_ref().and_then(standard_error),
        margin_se_pct: margin_pct.as_ref().and_then(standard_error),
        margin_m,
        margin_pct,
        margin_t,
        vs_baseline,
    })
}

/// The paired test of an arm's test RMSE (`rmse`, m) against the baseline's at size `n` over
/// the seeds of `p`; `None` for the baseline itself or a cell without an RMSE.
fn baseline_verdict(
    runs: &[RunRecord],
    n: usize,
    arm: &str,
    baseline: &str,
    rmse: Option<Stat>,
    p: &[(u64, f64, f64)],
) -> Option<Verdict> {
    let base_rmse = Stat::of(
        &pairs(runs, n, baseline, baseline)
            .iter()
            .map(|x| x.2)
            .collect::<Vec<_>>(),
    );
    match (arm == baseline, rmse, base_rmse) {
        (false, Some(a), Some(b)) => Some(verdict(arm, baseline, "rmse", &a, &b, p)),
        _ => None,
    }
}

/// Radar's margin per seed of `p` (seed, arm RMSE, baseline RMSE): (baseline − arm in m, the
/// same in % of the baseline); both `None` for the baseline itself.
fn margins(p: &[(u64, f64, f64)], is_base: bool) -> (Option<Stat>, Option<Stat>) {
    let margin_m = (!is_base)
        .then(|| Stat::of(&p.iter().map(|x| x.2 - x.1).collect::<Vec<_>>()))
        .flatten();
    let margin_pct = (!is_base)
        .then(|| {
            Stat::of(
                &p.iter()
                    .map(|x| 100.0 * (x.2 - x.1) / x.2)
                    .collect::<Vec<_>>(),
            )
        })
        .flatten();
    (margin_m, margin_pct)
}

/// Standard error of a seed mean (None below 2 seeds).
fn standard_error(s: &Stat) -> Option<f64> {
    s.std.map(|sd| sd / (s.n as f64).sqrt())
}

/// How the second arm's margin changed from the smallest to the largest N, in words.
fn trend(opts: &DataScaleOptions, rows: &[ScaleRow]) -> Option<String> {
    let arm = opts.arms.get(1)?;
    let lo = *opts.sizes.iter().min()?;
    let hi = *opts.sizes.iter().max()?;
    if lo == hi {
        return None;
    }
    let m = |n: usize| {
        rows.iter()
            .find(|r| r.train_samples == n && r.arm == arm.label)
            .and_then(|r| r.margin_m)
    };
    let (a, b) = (m(lo)?, m(hi)?);
    let growth = b.mean - a.mean;
    let se = match (standard_error(&a), standard_error(&b)) {
        (Some(x), Some(y)) => Some((x * x + y * y).sqrt()),
        _ => None,
    };
    let verdict = match se {
        Some(se) if growth.abs() > 2.0 * se => {
            if growth > 0.0 {
                "the margin GROWS with the training data (by more than 2 standard errors)"
            } else {
                "the margin SHRINKS with the training data (by more than 2 standard errors)"
            }
        }
        Some(_) => "the change is within 2 standard errors: no trend shown",
        None => "too few seeds for a standard error: no verdict",
    };
    Some(format!(
        "{} vs {}: margin {} m at N = {lo}, {} m at N = {hi} (change {} m{}); {verdict}",
        arm.label,
        opts.arms[0].label,
        super::signed(a.mean, 3),
        super::signed(b.mean, 3),
        super::signed(growth, 3),
        se.map_or(String::new(), |s| format!(" ± {s:.3}")),
    ))
}

fn write_outputs(r: &DataScaleResult) -> Result<(), ExperimentError> {
    let dir = &r.options.out;
    super::save_record(&dir.join(JSON_FILE), &dir.join(MD_FILE), r, &document(r))?;
    super::save(&dir.join(CSV_FILE), csv(r).as_bytes())?;
    super::save(&dir.join(PNG_FILE), &chart(r)?)
}

/// A panel's (name, points) and error bars of named series.
#[allow(clippy::type_complexity)]
fn series_parts(
    v: &[(String, Vec<(f64, f64)>, Vec<f64>)],
) -> (Vec<(&str, Vec<(f64, f64)>)>, Vec<Vec<f64>>) {
    v.iter()
        .map(|(n, p, e)| ((n.as_str(), p.clone()), e.clone()))
        .unzip()
}

/// Left: each arm's margin over the baseline (mean, bars ± one standard error) against the
/// training-set size (log axis); right: each arm's test RMSE (mean, bars ± one standard error).
fn chart(r: &DataScaleResult) -> Result<Vec<u8>, ExperimentError> {
    type Series = (String, Vec<(f64, f64)>, Vec<f64>);
    let x = |n: usize| (n as f64).log10();
    let series = |arm: &Arm, get: fn(&ScaleRow) -> Option<Stat>| -> Option<Series> {
        let pts: Vec<(f64, Stat)> = r
            .rows
            .iter()
            .filter(|row| row.arm == arm.label)
            .filter_map(|row| Some((x(row.train_samples), get(row)?)))
            .collect();
        (!pts.is_empty()).then(|| {
            (
                arm.label.clone(),
                pts.iter().map(|(x, s)| (*x, s.mean)).collect(),
                pts.iter()
                    .map(|(_, s)| standard_error(s).unwrap_or(f64::NAN))
                    .collect(),
            )
        })
    };
    let arms: Vec<&Arm> = r.options.arms.iter().chain(&r.options.at_largest).collect();
    // The baseline has no margin: its colour slot stays empty so that colours match across panels.
    let margin: Vec<Series> = arms
        .iter()
        .map(|a| series(a, |row| row.margin_m).unwrap_or((String::new(), vec![], vec![])))
        .collect();
    let rmse: Vec<Series> = arms
        .iter()
        .filter_map(|a| series(a, |row| row.rmse))
        .collect();
    let (m_series, m_err) = series_parts(&margin);
    let (r_series, r_err) = series_parts(&rmse);
    let title = format!(
        "radar's margin: {} test RMSE − the arm's (m)",
        r.options.arms[0].label
    );
    let panels = [
        depthsense_viz::plot::LinePanel {
            title: &title,
            x_label: "distinct training images (log scale)",
            y_label: "margin (m), ± 1 standard error",
            series: &m_series,
            error_bars: &m_err,
            log10_x: true,
        },
        depthsense_viz::plot::LinePanel {
            title: "test RMSE (m), mean over seeds",
            x_label: "distinct training images (log scale)",
            y_label: "RMSE (m), ± 1 standard error",
            series: &r_series,
            error_bars: &r_err,
            log10_x: true,
        },
    ];
    Ok(depthsense_viz::plot::line_charts_png(&panels)?)
}

/// The margin table with its setup (data_scale.md, and the report's section).
fn document(r: &DataScaleResult) -> Doc {
    let o = &r.options;
    let mut doc = Doc::new();
    doc.heading(1, "Radar's margin against training-set size");
    doc.paragraph(setup_text(r));
    doc.table(margin_table(r));
    if let Some(tr) = &r.trend {
        doc.paragraph(format!("**Trend.** {tr}."));
    }
    doc.paragraph(format!(
        "Machine: {}; the runs took {:.1} s of training and test in all, this invocation {:.1} s.",
        r.machine.line(),
        r.runs
            .iter()
            .map(|x| x.wall_seconds)
            .filter(|x| x.is_finite())
            .sum::<f64>(),
        r.total_seconds
    ))
    .command(o.command_line.as_deref());
    doc
}

/// The setup paragraph of the data-scale document: the network, the schedule, the data and
/// the seeds every run shares, and what the margin means.
fn setup_text(r: &DataScaleResult) -> String {
    let o = &r.options;
    format!(
        "Every run trains `{}`{} for the same **{} iterations** of batch {} ({} images seen), \
         validated every {} iterations on the same {} validation samples, its best checkpoint \
         tested on the same **test** scenes ({} samples: {}). The t of the margin is the paired \
         t-test's over seeds (positive: the arm is better), its verdict at 5 % two-sided. N distinct training samples are \
         nested subsets of the {} training samples, the same for every seed and arm. Seeds \
         {:?}; full image, cap {} m. Margin = {}'s test RMSE − the arm's, per seed (positive: \
         the arm is better); ± is the standard error of the mean over seeds.",
        o.run.preset,
        if o.run.set.is_empty() {
            String::new()
        } else {
            format!(" with {}", o.run.set.join(", "))
        },
        r.iterations,
        o.run.schedule.batch_size,
        r.iterations * o.run.schedule.batch_size as u64,
        r.epoch_iterations,
        o.run
            .validation
            .max_val_samples
            .map_or(r.partition.val_samples, |m| m.min(r.partition.val_samples)),
        r.partition.test_samples,
        r.partition.test_scenes.join(", "),
        r.partition.train_samples,
        o.seeds,
        o.eval.main_cap(),
        o.arms[0].label
    )
}

/// The margin table: one row per (N, arm) cell (RMSE and margin in m, ± a standard error).
fn margin_table(r: &DataScaleResult) -> MdTable {
    let mut t = MdTable::new(&[
        ("N", Align::Right),
        ("passes", Align::Right),
        ("arm", Align::Left),
        ("test RMSE (m)", Align::Right),
        ("δ1", Align::Right),
        ("margin (m)", Align::Right),
        ("margin (%)", Align::Right),
        ("t (margin)", Align::Right),
        ("verdict", Align::Left),
    ]);
    for row in &r.rows {
        let se_cell = |s: Option<Stat>, se: Option<f64>, prec: usize| {
            s.map_or("–".to_string(), |s| match se {
                Some(se) => format!("{} ± {se:.prec$}", super::signed(s.mean, prec)),
                None => super::signed(s.mean, prec),
            })
        };
        let p = row.vs_baseline.as_ref().and_then(|v| v.paired.as_ref());
        t.row(&[
            row.train_samples.to_string(),
            format!("{:.1}", row.passes),
            row.arm.clone(),
            Stat::md_cell(row.rmse),
            Stat::md_cell(row.delta1),
            se_cell(row.margin_m, row.margin_se_m, 3),
            se_cell(row.margin_pct, row.margin_se_pct, 1),
            row.margin_t.map_or("–".into(), |t| super::signed(t, 2)),
            match p.and_then(|p| p.significant) {
                Some(true) => "significant (5 %)".into(),
                Some(false) => "inside the seed noise".into(),
                None if row.vs_baseline.is_some() => "n < 2".into(),
                None => "baseline".into(),
            },
        ]);
    }
    t
}

fn csv(r: &DataScaleResult) -> String {
    let mut s = String::from(
        "train_samples,arm,seed,iterations,rmse_m,mae_m,abs_rel,delta1,best_val_rmse_m,train_seconds\n",
    );
    for run in &r.runs {
        let Some(h) = run.headline() else { continue };
        s.push_str(&csv_row(&[
            size_of(run).to_string(),
            csv_quoted(&run.variant),
            run.seed.to_string(),
            r.iterations.to_string(),
            format!("{:.6}", h.rmse),
            format!("{:.6}", h.mae),
            format!("{:.6}", h.abs_rel),
            format!("{:.6}", h.delta1),
            run.best_val_rmse
                .map_or(String::new(), |v| format!("{v:.6}")),
            format!("{:.3}", run.train_seconds),
        ]));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use depthsense_config::training::ScheduleOptions;

    fn opts(
        sizes: &[usize],
        batch: usize,
        epochs: usize,
        iterations: Option<u64>,
    ) -> DataScaleOptions {
        DataScaleOptions {
            run: RunSettings {
                schedule: ScheduleOptions {
                    batch_size: batch,
                    epochs,
                    ..Default::default()
                },
                ..RunSettings::default()
            },
            out: PathBuf::new(),
            sizes: sizes.to_vec(),
            arms: vec!["rgb".parse().unwrap(), "late-sam".parse().unwrap()],
            at_largest: vec![],
            seeds: vec![0],
            iterations,
            eval: EvalConfig::default(),
            command_line: None,
        }
    }

    #[test]
    fn the_schedule_shows_the_largest_set_once() {
        // 3000 images, batch 4: 750 iterations, 10 validations of 75.
        assert_eq!(schedule(&opts(&[100, 3000], 4, 10, None)), (750, 75));
        // 1001 images, batch 4: 251 iterations → rounded up to 7 × 36 = 252.
        assert_eq!(schedule(&opts(&[1001], 4, 7, None)), (252, 36));
        assert_eq!(schedule(&opts(&[10], 4, 2, Some(9))), (10, 5));
        assert_eq!(
            check(&opts(&[100], 4, 2, Some(24)), 200),
            Err(SpecRefusal::TooFewIterations {
                iterations: 24,
                batch: 4,
                largest: 100,
                needed: 25
            }),
            "24 × 4 < 100"
        );
        assert!(check(&opts(&[100], 4, 2, Some(25)), 200).is_ok());
        let mut o = opts(&[100], 4, 2, None);
        o.run.schedule.epoch_iterations = Some(10);
        let e = check(&o, 200).unwrap_err();
        assert_eq!(e, SpecRefusal::EpochIterationsGiven);
        assert!(e.to_string().contains("--epoch-iterations"), "{e}");
        let e = check(&opts(&[300], 4, 2, None), 200).unwrap_err();
        assert!(
            matches!(
                e,
                SpecRefusal::SizeExceedsData {
                    size: 300,
                    available: 200,
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("--sizes"), "{e}");
    }

    /// Empty, zero and repeated items are refused by name.
    #[test]
    fn the_lists_are_checked_item_by_item() {
        let mut o = opts(&[100], 4, 2, None);
        o.arms.clear();
        assert_eq!(check(&o, 200), Err(SpecRefusal::NothingGiven("arms")));
        assert_eq!(
            check(&opts(&[0, 100], 4, 2, None), 200),
            Err(SpecRefusal::ZeroSize)
        );
        let mut o = opts(&[100], 4, 2, None);
        o.at_largest = vec![o.arms[0].clone()];
        assert_eq!(
            check(&o, 200),
            Err(SpecRefusal::GivenTwice {
                what: "arm",
                item: o.arms[0].label.clone()
            })
        );
    }

    #[test]
    fn arms_parse_variant_and_options() {
        let a: Arm = "late-sam+radar-skip=8".parse().unwrap();
        assert_eq!(
            (a.variant, a.set.clone()),
            (Variant::LateSam, vec!["radar-skip=8".to_string()])
        );
        let m = a.model(&ModelConfig::tiny()).unwrap();
        assert_eq!(m.radar_skip_channels, 8);
        assert!(matches!(
            "late-sam+fusion=early".parse::<Arm>(),
            Err(ExperimentError::Spec(SpecRefusal::ArmSetting { setting, .. })) if setting == "fusion=early"
        ));
        assert!("late-sam+radar-skip".parse::<Arm>().is_err());
        assert!("rbg".parse::<Arm>().is_err());
        assert!("late-sam+radar-skipp=8"
            .parse::<Arm>()
            .unwrap()
            .model(&ModelConfig::tiny())
            .is_err());
        assert!(!a.radar_oracle);
        let o: Arm = "late-sam+oracle+radar-skip=8".parse().unwrap();
        assert!(o.radar_oracle);
        assert_eq!(o.set, vec!["radar-skip=8".to_string()]);
        assert_eq!(
            run_dir(std::path::Path::new("o"), 3000, &o, 2),
            std::path::Path::new("o/runs/n3000/late-sam_oracle_radar-skip_8/seed2")
        );
        let e = "rgb+oracle".parse::<Arm>().unwrap_err();
        assert!(
            matches!(&e, ExperimentError::Spec(SpecRefusal::OracleWithoutRadar { arm }) if arm == "rgb+oracle"),
            "{e}"
        );
        assert!(e.to_string().contains("late-sam+oracle"), "{e}");
    }
}
