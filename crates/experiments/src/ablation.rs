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

use depthsense_config::variant::Variant;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Instant;

use crate::{ExperimentError, SpecRefusal};
use depthsense_config::ModelConfig;
use depthsense_dataset::{partition, Dataset, Partition};
use depthsense_metrics::doc::Doc;
use depthsense_metrics::table::{csv_field, csv_num, csv_row, md_num, Align, MdTable};
use depthsense_metrics::EvalConfig;
use depthsense_progress::Board;
use serde::{Deserialize, Serialize};

use super::paired::{paired_test, PairedTest};
use super::runner::{run_bar, train_and_test, RunSettings};
pub use super::runner::{
    summarise, PartitionInfo, RowValues, RunRecord, RunStatus, SummaryRow, RUN_EVAL_FILE,
};
use super::{signed, Machine, Stat};

pub const MD_FILE: &str = "ablation.md";
pub const CSV_FILE: &str = "ablation.csv";
pub const JSON_FILE: &str = "ablation.json";
pub const PNG_FILE: &str = "ablation.png";
/// The baseline every other variant is compared with.
pub const BASELINE: &str = "rgb";

/// Everything an ablation is made of.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AblationOptions {
    /// Data, preset, `set` (which may not name fusion, attention or head: those are the
    /// variant's) and the training settings shared by every run.
    #[serde(flatten)]
    pub run: RunSettings,
    /// Output directory (runs/, ablation.{md,csv,json,png}).
    pub out: PathBuf,
    pub variants: Vec<Variant>,
    pub seeds: Vec<u64>,
    /// Test metrics settings (caps, protocol, aggregation).
    pub eval: EvalConfig,
    /// The invocation, recorded in the outputs (informational).
    pub command_line: Option<String>,
}

impl Default for AblationOptions {
    fn default() -> Self {
        Self {
            run: RunSettings::default(),
            out: PathBuf::from("runs/ablation"),
            variants: Variant::ALL.to_vec(),
            seeds: vec![0, 1, 2, 3, 4],
            eval: EvalConfig::default(),
            command_line: None,
        }
    }
}

/// A variant against the baseline on one headline metric (combined, full image).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    pub variant: String,
    pub baseline: String,
    /// "rmse", "delta1" or "abs_rel".
    pub metric: String,
    pub mean: f64,
    pub baseline_mean: f64,
    /// mean − baseline mean.
    pub difference: f64,
    /// 100 · difference / baseline mean.
    pub relative_pct: f64,
    /// The seeds both variants ran: the pairs of the test.
    pub paired_seeds: Vec<u64>,
    /// The paired test over those seeds (`None` when no seed is shared).
    pub paired: Option<PairedTest>,
    pub n: usize,
    pub baseline_n: usize,
    pub text: String,
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
    mp: &Board,
) -> Result<(RunRecord, RunStatus), ExperimentError> {
    let run = opts
        .out
        .join("runs")
        .join(variant.name())
        .join(format!("seed{seed}"));
    let topts = opts.run.train_options(run, model, seed);
    train_and_test(
        variant.name(),
        &topts,
        &opts.eval,
        ds,
        &part.test,
        device,
        mp,
    )
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
pub(crate) fn base_model(spec: &str) -> Result<ModelConfig, ExperimentError> {
    Ok(depthsense_checkpoint::config::resolve(spec)?)
}

/// The model config of each variant (preset → `set` → variant fields).
pub fn variant_models(
    opts: &AblationOptions,
) -> Result<Vec<(Variant, ModelConfig)>, ExperimentError> {
    for s in &opts.run.set {
        let key = s.split_once('=').map_or(s.as_str(), |(k, _)| k).trim();
        if ["fusion", "attention", "head", "loss"].contains(&key) {
            return Err(SpecRefusal::SetsVariantKey {
                setting: s.clone(),
                key: key.to_string(),
            }
            .into());
        }
    }
    let base = base_model(&opts.run.preset)?.with_options(&opts.run.set)?;
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

fn check_options(opts: &AblationOptions) -> Result<(), SpecRefusal> {
    if opts.variants.is_empty() {
        return Err(SpecRefusal::NothingGiven("ablation variants"));
    }
    if opts.seeds.is_empty() {
        return Err(SpecRefusal::NothingGiven("seeds"));
    }
    let dup = |names: Vec<String>| {
        let mut s = names.clone();
        s.sort();
        s.windows(2).find(|w| w[0] == w[1]).map(|w| w[0].clone())
    };
    if let Some(d) = dup(opts.variants.iter().map(|v| v.name().to_string()).collect()) {
        return Err(SpecRefusal::GivenTwice {
            what: "variant",
            item: d,
        });
    }
    if let Some(d) = dup(opts.seeds.iter().map(|s| s.to_string()).collect()) {
        return Err(SpecRefusal::GivenTwice {
            what: "seed",
            item: d,
        });
    }
    Ok(())
}

/// The verdict rule: a paired test over the seeds both variants ran (each seed trains both,
/// [`paired_test`]): the mean per-seed difference, its standard error and a two-sided paired
/// t-test at 5 %; no verdict with fewer than 2 shared seeds. `values` are (seed, variant value,
/// baseline value) of the seeds both ran.
pub fn verdict(
    variant: &str,
    baseline: &str,
    metric: &str,
    v: &Stat,
    b: &Stat,
    values: &[(u64, f64, f64)],
) -> Verdict {
    let diff = v.mean - b.mean;
    let rel = 100.0 * diff / b.mean;
    let pairs: Vec<(f64, f64)> = values.iter().map(|&(_, a, c)| (a, c)).collect();
    let paired = paired_test(&pairs);
    let (label, unit, prec) = metric_words(metric);
    let test_txt = paired_text(paired.as_ref(), unit, prec);
    let text = format!(
        "{variant} vs {baseline}: {label} {} % (mean {:.prec$}{unit} vs {:.prec$}{unit}, n = {} / {}); {test_txt}",
        signed(rel, 1),
        v.mean,
        b.mean,
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
        paired_seeds: values.iter().map(|x| x.0).collect(),
        paired,
        n: v.n,
        baseline_n: b.n,
        text,
    }
}

/// A metric's (name shown, unit suffix, decimals) in a verdict's sentence.
fn metric_words(metric: &str) -> (&'static str, &'static str, usize) {
    match metric {
        "rmse" => ("RMSE", " m", 3),
        "abs_rel" => ("AbsRel", "", 4),
        _ => ("δ1", "", 3),
    }
}

/// The paired test's part of a verdict's sentence: the mean difference ± its standard error
/// (`unit`, `prec` decimals), t and the decision, or why there is no verdict.
fn paired_text(paired: Option<&PairedTest>, unit: &str, prec: usize) -> String {
    match paired {
        Some(p) => match (p.standard_error, p.t, p.t_critical, p.significant) {
            (Some(se), Some(t), Some(c), Some(sig)) => format!(
                "paired over {} seeds: difference {} ± {se:.prec$}{unit} (standard error), t = {}, |t| {} {c:.3} = t₀.₉₇₅ with {} df → {}",
                p.n,
                signed(p.mean_difference, prec),
                signed(t, 2),
                if sig { ">" } else { "≤" },
                p.n - 1,
                if sig {
                    "significant (two-sided paired t-test, 5 %)"
                } else {
                    "NOT significant: inside the seed-to-seed noise"
                }
            ),
            _ if p.n == 1 => {
                "one seed shared: no verdict (one seed: not a finding; a paired test needs 2)"
                    .to_string()
            }
            _ => format!(
                "{} shared seed(s): no verdict (a paired test needs 2)",
                p.n
            ),
        },
        None => "no seed shared with the baseline: no verdict".to_string(),
    }
}

/// (seed, variant value, baseline value) of the seeds both ran, from each run's headline row.
fn seed_pairs(
    runs: &[RunRecord],
    variant: &str,
    baseline: &str,
    get: Field,
) -> Vec<(u64, f64, f64)> {
    let value = |name: &str, seed: u64| {
        runs.iter()
            .find(|r| r.variant == name && r.seed == seed)
            .and_then(|r| r.headline())
            .map(get)
    };
    let mut seeds: Vec<u64> = runs
        .iter()
        .filter(|r| r.variant == variant)
        .map(|r| r.seed)
        .collect();
    seeds.sort_unstable();
    seeds.dedup();
    seeds
        .into_iter()
        .filter_map(|s| Some((s, value(variant, s)?, value(baseline, s)?)))
        .collect()
}

/// A headline metric of one run.
type Field = fn(&RowValues) -> f64;

fn verdicts(variants: &[&str], summary: &[SummaryRow], runs: &[RunRecord]) -> Vec<Verdict> {
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
        let metrics: [(&str, Option<Stat>, Option<Stat>, Field); 3] = [
            ("rmse", row.rmse, base.rmse, |x| x.rmse),
            ("delta1", row.delta1, base.delta1, |x| x.delta1),
            ("abs_rel", row.abs_rel, base.abs_rel, |x| x.abs_rel),
        ];
        for (metric, a, b, field) in metrics {
            if let (Some(a), Some(b)) = (a, b) {
                let pairs = seed_pairs(runs, v, BASELINE, field);
                out.push(verdict(v, BASELINE, metric, &a, &b, &pairs));
            }
        }
    }
    out
}

/// A partition with test samples: the ablation reports on the test scenes only.
fn require_test(opts: &AblationOptions, part: &Partition) -> Result<(), ExperimentError> {
    if part.test.is_empty() {
        return Err(ExperimentError::NoTestSamples {
            data: opts.run.data.clone(),
            method: part.method.to_string(),
            experiment: "the ablation",
        });
    }
    Ok(())
}

/// Run the ablation: every variant × seed, test evaluation, tables and chart in `opts.out`.
/// `mp` hosts one progress bar per run (pass a hidden one in tests).
pub fn run_ablation(opts: &AblationOptions, mp: &Board) -> Result<AblationResult, ExperimentError> {
    let t0 = Instant::now();
    check_options(opts)?;
    let models = variant_models(opts)?;
    let device = depthsense_model::device::parse_device(&opts.run.hardware.device.name)?;
    let ds = Dataset::open(&opts.run.data)?;
    let part = partition(&ds, opts.run.validation.val_every_scene)?;
    require_test(opts, &part)?;
    // One writer per experiment folder (each run's folder has its own lock too).
    let _writing =
        depthsense_base::lock::OutputLock::exclusive(&opts.out, "depthsense experiment ablation")?;
    let total = models.len() * opts.seeds.len();
    let overall = run_bar(mp, "ablation runs");
    overall.set_length(total as u64);
    overall.println(format!(
        "{} variants × {} seeds = {total} runs into {}",
        models.len(),
        opts.seeds.len(),
        opts.out.display()
    ));
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
    let verdicts = verdicts(&names, &summary, &runs);
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

fn write_outputs(dir: &Path, r: &AblationResult) -> Result<(), ExperimentError> {
    super::save_record(&dir.join(JSON_FILE), &dir.join(MD_FILE), r, &document(r))?;
    super::save(&dir.join(CSV_FILE), csv(r).as_bytes())?;
    super::save(&dir.join(PNG_FILE), &chart(r)?)?;
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

fn chart(r: &AblationResult) -> Result<Vec<u8>, ExperimentError> {
    let (names, [rm, rs, dm, dsd]) = headline_stats(r);
    let n = r.options.seeds.len();
    let t1 = format!("test RMSE (m), mean ± std over {n} seed(s)");
    let t2 = format!("test δ1, mean ± std over {n} seed(s)");
    Ok(depthsense_viz::plot::bar_charts_png(&[
        depthsense_viz::plot::BarPanel {
            title: &t1,
            labels: &names,
            means: &rm,
            stds: &rs,
            y_label: "RMSE (m)",
        },
        depthsense_viz::plot::BarPanel {
            title: &t2,
            labels: &names,
            means: &dm,
            stds: &dsd,
            y_label: "δ1",
        },
    ])?)
}

fn csv(r: &AblationResult) -> String {
    let mut s = String::from(
        "kind,variant,seed,condition,region,cap_m,n,n_images,delta1,delta1_std,rmse_m,rmse_std_m,\
         abs_rel,abs_rel_std,mae_m,mae_std_m,train_s,eval_s,wall_s\n",
    );
    for run in &r.runs {
        for x in &run.rows {
            s.push_str(&run_csv_row(run, x));
        }
    }
    for x in &r.summary {
        s.push_str(&mean_csv_row(x));
    }
    s
}

/// The CSV line of one run's row `x` (kind `run`; metres, seconds).
fn run_csv_row(run: &RunRecord, x: &RowValues) -> String {
    let f6 = |v: f64| format!("{v:.6}");
    let f2 = |v: f64| format!("{v:.2}");
    csv_row(&[
        "run".to_string(),
        csv_field(&run.variant),
        run.seed.to_string(),
        csv_field(&x.condition),
        csv_field(&x.region),
        x.cap_m.to_string(),
        "1".into(),
        x.n_images.to_string(),
        f6(x.delta1),
        String::new(),
        f6(x.rmse),
        String::new(),
        f6(x.abs_rel),
        String::new(),
        f6(x.mae),
        String::new(),
        f2(run.train_seconds),
        f2(run.eval_seconds),
        f2(run.wall_seconds),
    ])
}

/// The CSV line of a summary row (kind `mean`: mean and std over seeds; metres).
fn mean_csv_row(x: &SummaryRow) -> String {
    let st = |s: &Option<Stat>| {
        (
            csv_num(s.map(|s| s.mean), 6),
            csv_num(s.and_then(|s| s.std), 6),
        )
    };
    let (d, ds) = st(&x.delta1);
    let (rm, rs) = st(&x.rmse);
    let (a, as_) = st(&x.abs_rel);
    let (m, ms) = st(&x.mae);
    csv_row(&[
        "mean".to_string(),
        csv_field(&x.variant),
        String::new(),
        csv_field(&x.condition),
        csv_field(&x.region),
        csv_num(Some(x.cap_m), 0),
        x.n.to_string(),
        String::new(),
        d,
        ds,
        rm,
        rs,
        a,
        as_,
        m,
        ms,
        String::new(),
        String::new(),
        String::new(),
    ])
}

/// The paper's MER table (SPEC §5 / §10): every variant, full image and low-height, combined
/// conditions at `cap_m`, δ1–3, RMSE, AbsRel and RMSE_log (mean ± std over seeds, from each
/// run's full test report). Written only when the ablation has the `late-sam-mer` variant.
/// The paper's MER table (heading and table; no block without a `late-sam-mer` run).
pub fn mer_table(r: &AblationResult, cap_m: f64) -> Doc {
    let mut doc = Doc::new();
    if !r
        .runs
        .iter()
        .any(|x| x.variant == Variant::LateSamMer.name())
    {
        return doc;
    }
    type Get = fn(&depthsense_metrics::Metrics) -> f64;
    let cols: [Get; 6] = [
        |m| m.delta1,
        |m| m.delta2,
        |m| m.delta3,
        |m| m.rmse,
        |m| m.abs_rel,
        |m| m.rmse_log,
    ];
    doc.heading(
        2,
        format!("MER table: full image and low-height, cap {cap_m:.0} m (test scenes)"),
    );
    let mut t = MdTable::new(&[
        ("variant", Align::Left),
        ("region", Align::Left),
        ("n", Align::Right),
        ("δ1", Align::Right),
        ("δ2", Align::Right),
        ("δ3", Align::Right),
        ("RMSE (m)", Align::Right),
        ("AbsRel", Align::Right),
        ("RMSE_log", Align::Right),
    ]);
    for (name, _) in &r.models {
        for region in ["full", "lowheight"] {
            let rows: Vec<&depthsense_metrics::Row> = r
                .runs
                .iter()
                .filter(|x| &x.variant == name)
                .filter_map(|x| x.report.row("combined", region, cap_m))
                .collect();
            let mut cells = vec![
                name.clone(),
                depthsense_metrics::region_label(region).to_string(),
                rows.len().to_string(),
            ];
            cells.extend(cols.iter().map(|g| {
                Stat::md_cell(Stat::of(
                    &rows.iter().map(|x| g(&x.metrics)).collect::<Vec<_>>(),
                ))
            }));
            t.row(&cells);
        }
    }
    doc.table(t);
    doc
}

/// ablation.md, and the report's section: intro, verdicts, tables, per run, setup.
fn document(r: &AblationResult) -> Doc {
    let mut doc = Doc::new();
    md_intro(r, &mut doc);
    md_verdicts(r, &mut doc);
    let cap = r
        .summary
        .iter()
        .map(|x| x.cap_m)
        .find(|c| c.is_finite())
        .unwrap_or(r.options.eval.main_cap());
    md_region_tables(r, cap, &mut doc);
    doc.blocks.extend(mer_table(r, cap).blocks);
    md_per_run(r, &mut doc);
    md_setup(r, &mut doc);
    doc
}

/// Title, what was run, and the variants' fields.
fn md_intro(r: &AblationResult, doc: &mut Doc) {
    let o = &r.options;
    let seeds: Vec<String> = o.seeds.iter().map(|s| s.to_string()).collect();
    doc.heading(
        1,
        "Ablation: fusion variants and loss (SPEC §6, §10.1, §10.4)",
    );
    doc.paragraph(format!(
        "Each variant trained with seeds {} (n = {} per variant) on the same data; each run's \
         `best.safetensors` (lowest RMSE on the validation scenes) evaluated on the **test** \
         scenes. Values: mean ± sample std over seeds (divisor n − 1; \"–\" when n < 2).",
        seeds.join(", "),
        seeds.len()
    ));
    let mut t = MdTable::new(&[
        ("variant", Align::Left),
        ("fusion", Align::Left),
        ("attention", Align::Left),
        ("head", Align::Left),
        ("description", Align::Left),
    ]);
    for (name, c) in &r.models {
        let desc = Variant::from_str(name).map_or("", |v| v.describe());
        t.row(&[
            name.clone(),
            format!("{:?}", c.fusion),
            c.attention.to_string(),
            format!("{:?}", c.head),
            desc.to_string(),
        ]);
    }
    doc.table(t);
}

/// The paired verdicts against rgb (nothing without any).
fn md_verdicts(r: &AblationResult, doc: &mut Doc) {
    if !r.verdicts.is_empty() {
        doc.heading(2, "Verdicts vs rgb (combined, full image)");
        doc.paragraph(
            "Rule: each seed trains both the variant and rgb, so the test is paired over the \
             seeds both ran: the per-seed differences (variant − rgb), their mean ± standard \
             error (sd/√n), and a two-sided paired t-test at 5 % (Student's t, n − 1 degrees of \
             freedom). A difference that is not significant is not a finding; with fewer than 2 \
             shared seeds there is no verdict.",
        );
        doc.list(r.verdicts.iter().map(|v| v.text.clone()));
    }
}

/// Full image and low-height tables at `cap` m (test scenes).
fn md_region_tables(r: &AblationResult, cap: f64, doc: &mut Doc) {
    for (region, title) in [("full", "Full image"), ("lowheight", "Low-height region")] {
        doc.heading(2, format!("{title}, cap {cap:.0} m (test scenes)"));
        let mut t = MdTable::new(&[
            ("variant", Align::Left),
            ("condition", Align::Left),
            ("n", Align::Right),
            ("δ1", Align::Right),
            ("RMSE (m)", Align::Right),
            ("AbsRel", Align::Right),
            ("MAE (m)", Align::Right),
        ]);
        for x in r.summary.iter().filter(|x| x.region == region) {
            t.row(&[
                x.variant.clone(),
                x.condition.clone(),
                x.n.to_string(),
                Stat::md_cell(x.delta1),
                Stat::md_cell(x.rmse),
                Stat::md_cell(x.abs_rel),
                Stat::md_cell(x.mae),
            ]);
        }
        doc.table(t);
    }
}

/// Per run (combined, full image).
fn md_per_run(r: &AblationResult, doc: &mut Doc) {
    doc.heading(2, "Per run (combined, full image)");
    let mut t = MdTable::new(&[
        ("variant", Align::Left),
        ("seed", Align::Right),
        ("δ1", Align::Right),
        ("RMSE (m)", Align::Right),
        ("AbsRel", Align::Right),
        ("MAE (m)", Align::Right),
        ("best val RMSE (m)", Align::Right),
        ("train s", Align::Right),
        ("eval s", Align::Right),
        ("this invocation", Align::Left),
    ]);
    for (run, st) in r.runs.iter().zip(&r.status) {
        let h = run.headline();
        let f = |g: fn(&RowValues) -> f64| md_num(h.map(g), 3);
        t.row(&[
            run.variant.clone(),
            run.seed.to_string(),
            f(|x| x.delta1),
            f(|x| x.rmse),
            f(|x| x.abs_rel),
            f(|x| x.mae),
            // An empty cell when absent (this column's look since it was added).
            csv_num(run.best_val_rmse, 3),
            format!("{:.1}", run.train_seconds),
            format!("{:.1}", run.eval_seconds),
            serde_json::to_value(st)
                .ok()
                .and_then(|v| v.as_str().map(String::from))
                .unwrap_or_default(),
        ]);
    }
    doc.table(t);
}

/// Partition, model, metrics, machine, this invocation, files.
fn md_setup(r: &AblationResult, doc: &mut Doc) {
    let o = &r.options;
    let p = &r.partition;
    let all = |m: Option<usize>| m.map_or("all".to_string(), |m| m.to_string());
    let set = if o.run.set.is_empty() {
        String::new()
    } else {
        format!(" with `--set {}`", o.run.set.join(" --set "))
    };
    let mut items = vec![
        format!(
            "Partition: {} — {} train, {} validation, {} test samples.",
            p.method, p.train_samples, p.val_samples, p.test_samples
        ),
        format!(
            "Validation scenes (checkpoint selection): {}",
            p.val_scenes.join(", ")
        ),
        format!(
            "Test scenes (reported above; never used for selection): {}",
            p.test_scenes.join(", ")
        ),
        format!(
            "Model preset `{}`{set}; {} epochs, batch {}, lr {}, max batches/epoch {}, max \
             validation samples {}.",
            o.run.preset,
            o.run.schedule.epochs,
            o.run.schedule.batch_size,
            o.run.schedule.lr,
            all(o.run.schedule.max_batches_per_epoch),
            all(o.run.validation.max_val_samples)
        ),
        format!(
            "Metrics: caps {:?} m, protocol {:?}, aggregation {:?}, prediction clipped to [{}, \
             {}] m (SPEC §9).",
            o.eval.caps_m, o.eval.protocol, o.eval.aggregate, o.eval.clip_min_m, o.eval.clip_max_m
        ),
        format!("Machine: {}.", r.machine.line()),
        format!(
            "This invocation: {} trained, {} resumed, {} evaluated only, {} skipped (finished \
             before); {:.1} s.",
            r.trained, r.resumed, r.evaluated, r.skipped, r.total_seconds
        ),
    ];
    if let Some(c) = &o.command_line {
        items.push(format!("Command: `{c}`"));
    }
    doc.heading(2, "Setup").list(items).paragraph(format!(
        "Files: `{CSV_FILE}` (per-run and mean rows), `{JSON_FILE}` (everything, with each \
         run's full report), `{PNG_FILE}` (test RMSE and δ1 per variant, error bars ± 1 std), \
         `runs/<variant>/seed<k>/` (training runs with their `{RUN_EVAL_FILE}`)."
    ));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runner::same_json;

    #[test]
    fn set_may_not_name_the_variants_fields() {
        let opts = AblationOptions {
            run: RunSettings {
                preset: "tiny".into(),
                set: vec!["head=l1".into()],
                ..RunSettings::default()
            },
            ..AblationOptions::default()
        };
        assert!(
            matches!(
                variant_models(&opts),
                Err(ExperimentError::Spec(SpecRefusal::SetsVariantKey { key, .. })) if key == "head"
            ),
            "--set head is the variant's"
        );
    }

    #[test]
    fn options_of_absent_parts_leave_the_other_variants_unchanged() {
        let with = |set: Vec<String>| {
            let opts = AblationOptions {
                run: RunSettings {
                    preset: "tiny".into(),
                    set,
                    ..RunSettings::default()
                },
                variants: vec![Variant::Rgb, Variant::Late, Variant::LateSam],
                ..AblationOptions::default()
            };
            variant_models(&opts).unwrap()
        };
        let plain = with(vec![]);
        let gated = with(vec!["attention-gate=bounded".into(), "radar-skip=8".into()]);
        assert_eq!(plain[0].1, gated[0].1, "rgb");
        assert_eq!(
            gated[1].1.attention_gate,
            Default::default(),
            "late has no attention"
        );
        assert_eq!(gated[1].1.radar_skip_channels, 8);
        assert_eq!(
            gated[2].1.attention_gate,
            depthsense_config::AttentionGate::Bounded
        );
    }

    #[test]
    fn verdict_is_a_paired_test_over_the_shared_seeds() {
        // Seeds move both variants alike; late-sam is 0.1 m better on every seed: the
        // unpaired stds (≈ 0.5 m) would hide it, the paired test finds it.
        let rgb_v = [10.0, 10.5, 9.5, 11.0];
        let sam_v = [9.9, 10.4, 9.4, 10.92];
        let rgb = Stat::of(&rgb_v).unwrap();
        let sam = Stat::of(&sam_v).unwrap();
        let pairs: Vec<(u64, f64, f64)> = (0..4)
            .map(|i| (i, sam_v[i as usize], rgb_v[i as usize]))
            .collect();
        let v = verdict("late-sam", "rgb", "rmse", &sam, &rgb, &pairs);
        assert!((v.difference - (sam.mean - rgb.mean)).abs() < 1e-12);
        let p = v.paired.clone().unwrap();
        assert_eq!(p.n, 4);
        assert!((p.mean_difference + 0.095).abs() < 1e-9);
        assert_eq!(p.significant, Some(true));
        assert_eq!(v.paired_seeds, vec![0, 1, 2, 3]);
        assert!(v.text.contains("paired over 4 seeds"), "{}", v.text);
        assert!(
            v.text
                .ends_with("significant (two-sided paired t-test, 5 %)"),
            "{}",
            v.text
        );
        // One seed against the grain: not significant.
        let noisy = [(0, 9.9, 10.0), (1, 10.7, 10.5), (2, 9.2, 9.5)];
        let v = verdict("late", "rgb", "rmse", &sam, &rgb, &noisy);
        assert_eq!(v.paired.unwrap().significant, Some(false));
        assert!(v.text.contains("NOT significant"), "{}", v.text);
        // One shared seed: no verdict, and the words say it is one seed.
        let v = verdict("l1", "rgb", "rmse", &sam, &rgb, &pairs[..1]);
        assert_eq!(v.paired.unwrap().significant, None);
        assert!(v.text.contains("no verdict"), "{}", v.text);
        assert!(v.text.contains("one seed: not a finding"), "{}", v.text);
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
