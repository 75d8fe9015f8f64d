//! Reduced training data (SPEC §10.5): `train --exclude night=1.0,rain=0.5` withholds a
//! fraction of one condition's TRAINING scenes, and `experiment reduced-data` trains a grid
//! of such exclusions (several seeds each) and tables the test metrics per test condition.
//!
//! The withholding rule is [`depthsense_data::exclusion::withheld_scenes`] (re-exported here).
//!
//! ```text
//! OUT/runs/<cell>/seed<k>/     an ordinary training run (+ eval.json, see `runner`)
//! OUT/reduced_data.{md,csv,json,png}
//! ```

use std::collections::BTreeSet;
use std::path::PathBuf;
use std::time::Instant;

use crate::{ExperimentError, SpecRefusal};
use depthsense_config::ModelConfig;
use depthsense_dataset::{partition, Dataset, Partition};
use depthsense_metrics::doc::Doc;
use depthsense_metrics::table::{csv_quoted, csv_row, Align, MdTable};
use depthsense_metrics::{EvalConfig, CONDITIONS};
use depthsense_progress::Board;
use depthsense_train::trainer::TrainOptions;
use serde::{Deserialize, Serialize};

use super::runner::{
    run_bar, summarise, train_and_test, PartitionInfo, RunRecord, RunSettings, SummaryRow,
};
use super::{Machine, Stat};

pub const MD_FILE: &str = "reduced_data.md";
pub const CSV_FILE: &str = "reduced_data.csv";
pub const JSON_FILE: &str = "reduced_data.json";
pub const PNG_FILE: &str = "reduced_data.png";

use depthsense_data::exclusion::*;

/// One cell of the grid: a name and its exclusions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Cell {
    pub name: String,
    pub exclude: Vec<Exclusion>,
}

/// Parse "full;night=1;rain=1;day=0.5" (cells separated by `;`).
pub fn parse_grid(s: &str) -> Result<Vec<Cell>, ExperimentError> {
    s.split(';')
        .filter(|c| !c.trim().is_empty())
        .map(|c| {
            let exclude = parse_exclusions(c)?;
            Ok(Cell {
                name: exclusions_label(&exclude),
                exclude,
            })
        })
        .collect()
}

/// Everything a reduced-data experiment is made of.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReducedDataOptions {
    /// Data, preset (the paper's late fusion + attention by default), `set` and the training
    /// settings shared by every run.
    #[serde(flatten)]
    pub run: RunSettings,
    pub out: PathBuf,
    pub grid: Vec<Cell>,
    pub seeds: Vec<u64>,
    pub eval: EvalConfig,
    pub command_line: Option<String>,
}

/// A cell's training set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CellInfo {
    pub name: String,
    pub train_samples: usize,
    pub withheld_scenes: Vec<String>,
}

/// Everything the experiment produced (= reduced_data.json).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReducedDataResult {
    pub options: ReducedDataOptions,
    pub machine: Machine,
    pub partition: PartitionInfo,
    pub cells: Vec<CellInfo>,
    pub runs: Vec<RunRecord>,
    pub summary: Vec<SummaryRow>,
    pub total_seconds: f64,
}

impl ReducedDataResult {
    pub fn row(&self, cell: &str, condition: &str) -> Option<&SummaryRow> {
        self.summary
            .iter()
            .find(|r| r.variant == cell && r.condition == condition && r.region == "full")
    }
}

fn check(opts: &ReducedDataOptions) -> Result<(), SpecRefusal> {
    if opts.grid.is_empty() {
        return Err(SpecRefusal::NothingGiven("grid cells"));
    }
    if opts.seeds.is_empty() {
        return Err(SpecRefusal::NothingGiven("seeds"));
    }
    let mut names = BTreeSet::new();
    if let Some(c) = opts.grid.iter().find(|c| !names.insert(c.name.as_str())) {
        return Err(SpecRefusal::GivenTwice {
            what: "grid cell",
            item: c.name.clone(),
        });
    }
    Ok(())
}

fn topts(opts: &ReducedDataOptions, model: &ModelConfig, cell: &Cell, seed: u64) -> TrainOptions {
    let run = opts
        .out
        .join("runs")
        .join(cell.name.replace([',', '='], "_"))
        .join(format!("seed{seed}"));
    TrainOptions {
        exclude: cell.exclude.clone(),
        ..opts.run.train_options(run, model, seed)
    }
}

/// A partition with test samples: reduced-data reports on the test scenes.
fn require_test(opts: &ReducedDataOptions, part: &Partition) -> Result<(), ExperimentError> {
    if part.test.is_empty() {
        return Err(ExperimentError::NoTestSamples {
            data: opts.run.data.clone(),
            method: part.method.to_string(),
            experiment: "reduced-data",
        });
    }
    Ok(())
}

/// Train every cell × seed, test on the test scenes, write the tables and the chart.
pub fn run_reduced_data(
    opts: &ReducedDataOptions,
    mp: &Board,
) -> Result<ReducedDataResult, ExperimentError> {
    let t0 = Instant::now();
    check(opts)?;
    let model = super::ablation::base_model(&opts.run.preset)?.with_options(&opts.run.set)?;
    let device = depthsense_model::device::parse_device(&opts.run.hardware.device.name)?;
    let ds = Dataset::open(&opts.run.data)?;
    let part = partition(&ds, opts.run.validation.val_every_scene)?;
    require_test(opts, &part)?;
    // One writer per experiment folder (each run's folder has its own lock too).
    let _writing = depthsense_base::lock::OutputLock::exclusive(
        &opts.out,
        "depthsense experiment reduced-data",
    )?;
    let overall = run_bar(mp, "reduced-data runs");
    overall.set_length((opts.grid.len() * opts.seeds.len()) as u64);
    overall.println(format!(
        "{} cells × {} seeds = {} runs into {}",
        opts.grid.len(),
        opts.seeds.len(),
        opts.grid.len() * opts.seeds.len(),
        opts.out.display()
    ));
    let (mut runs, mut cells) = (vec![], vec![]);
    for cell in &opts.grid {
        let mut p = part.clone();
        let gone = apply_exclusions(&mut p, &cell.exclude);
        cells.push(CellInfo {
            name: cell.name.clone(),
            train_samples: p.train.len(),
            withheld_scenes: gone,
        });
        for &seed in &opts.seeds {
            overall.set_message(format!("{} seed{seed}", cell.name));
            let t = topts(opts, &model, cell, seed);
            let (rec, _) = train_and_test(&cell.name, &t, &opts.eval, &ds, &part.test, device, mp)?;
            runs.push(rec);
            overall.inc(1);
        }
    }
    overall.finish_with_message("done");
    let names: Vec<&str> = opts.grid.iter().map(|c| c.name.as_str()).collect();
    let result = ReducedDataResult {
        options: opts.clone(),
        machine: Machine::describe(device),
        partition: PartitionInfo::from(&part),
        cells,
        summary: summarise(&names, &runs),
        runs,
        total_seconds: t0.elapsed().as_secs_f64(),
    };
    write_outputs(&result)?;
    Ok(result)
}

fn write_outputs(r: &ReducedDataResult) -> Result<(), ExperimentError> {
    let dir = &r.options.out;
    super::save_record(&dir.join(JSON_FILE), &dir.join(MD_FILE), r, &document(r))?;
    super::save(&dir.join(CSV_FILE), csv(r).as_bytes())?;
    super::save(&dir.join(PNG_FILE), &chart(r)?)
}

fn stat_of(
    r: &ReducedDataResult,
    cell: &str,
    cond: &str,
    f: fn(&SummaryRow) -> Option<Stat>,
) -> Option<Stat> {
    r.row(cell, cond).and_then(f)
}

fn chart(r: &ReducedDataResult) -> Result<Vec<u8>, ExperimentError> {
    let names: Vec<&str> = r.cells.iter().map(|c| c.name.as_str()).collect();
    let mut cols: Vec<(String, Vec<f64>, Vec<f64>)> = vec![];
    for cond in CONDITIONS {
        let (m, s): (Vec<f64>, Vec<f64>) = names
            .iter()
            .map(|n| {
                stat_of(r, n, cond, |x| x.rmse).map_or((f64::NAN, f64::NAN), |s| {
                    (s.mean, s.std.unwrap_or(f64::NAN))
                })
            })
            .unzip();
        cols.push((format!("test RMSE (m), {cond} scenes"), m, s));
    }
    let panels: Vec<depthsense_viz::plot::BarPanel> = cols
        .iter()
        .map(|(t, m, s)| depthsense_viz::plot::BarPanel {
            title: t,
            labels: &names,
            means: m,
            stds: s,
            y_label: "RMSE (m)",
        })
        .collect();
    Ok(depthsense_viz::plot::bar_charts_png(&panels)?)
}

/// The cells' tables with their setup (reduced_data.md, and the report's section).
fn document(r: &ReducedDataResult) -> Doc {
    let o = &r.options;
    let mut doc = Doc::new();
    doc.heading(1, "Reduced training data (SPEC §10.5)");
    doc.paragraph(format!(
        "Each cell trains `{}` with the listed training scenes withheld (rule: docs/guide/experiments.md, \
         \"Reduced training data\"), seeds {:?}, {} epoch(s); every run is selected on the \
         same validation scenes and tested on the same **test** scenes ({}). Mean ± std over \
         seeds, full image, cap {} m.",
        o.run.preset,
        o.seeds,
        o.run.schedule.epochs,
        r.partition.test_scenes.join(", "),
        o.eval.main_cap()
    ));
    for (title, f) in [
        (
            "Test RMSE (m) per test condition",
            (|x: &SummaryRow| x.rmse) as fn(&SummaryRow) -> Option<Stat>,
        ),
        ("Test δ1 per test condition", |x: &SummaryRow| x.delta1),
    ] {
        doc.heading(3, title);
        let mut t = MdTable::new(&[
            ("trained without", Align::Left),
            ("train samples", Align::Right),
            ("combined", Align::Right),
            ("day", Align::Right),
            ("night", Align::Right),
            ("rain", Align::Right),
        ]);
        for c in &r.cells {
            let mut cells = vec![c.name.clone(), c.train_samples.to_string()];
            cells.extend(
                CONDITIONS
                    .iter()
                    .map(|cond| Stat::md_cell(stat_of(r, &c.name, cond, f))),
            );
            t.row(&cells);
        }
        doc.table(t);
    }
    doc.heading(3, "Withheld training scenes");
    doc.list(r.cells.iter().map(|c| {
        let scenes = if c.withheld_scenes.is_empty() {
            "none".to_string()
        } else {
            c.withheld_scenes.join(", ")
        };
        format!("{}: {scenes}", c.name)
    }));
    doc.paragraph(format!(
        "Machine: {}; {:.1} s.",
        r.machine.line(),
        r.total_seconds
    ))
    .command(o.command_line.as_deref());
    doc
}

fn csv(r: &ReducedDataResult) -> String {
    let mut s = String::from("cell,seed,condition,n_images,delta1,rmse_m,abs_rel,mae_m\n");
    for run in &r.runs {
        for x in run.rows.iter().filter(|x| x.region == "full") {
            s.push_str(&csv_row(&[
                csv_quoted(&run.variant),
                run.seed.to_string(),
                x.condition.to_string(),
                x.n_images.to_string(),
                format!("{:.6}", x.delta1),
                format!("{:.6}", x.rmse),
                format!("{:.6}", x.abs_rel),
                format!("{:.6}", x.mae),
            ]));
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with(grid: &str, seeds: Vec<u64>) -> ReducedDataOptions {
        ReducedDataOptions {
            run: RunSettings::default(),
            out: PathBuf::from("out"),
            grid: parse_grid(grid).unwrap_or_default(),
            seeds,
            eval: EvalConfig::default(),
            command_line: None,
        }
    }

    /// An empty grid or seed list and a cell given twice are refused by name.
    #[test]
    fn the_grid_and_seeds_are_checked() {
        assert_eq!(check(&with("full;night=1", vec![0])), Ok(()));
        assert_eq!(
            check(&with("", vec![0])),
            Err(SpecRefusal::NothingGiven("grid cells"))
        );
        assert_eq!(
            check(&with("full", vec![])),
            Err(SpecRefusal::NothingGiven("seeds"))
        );
        assert_eq!(
            check(&with("full;night=1;full", vec![0])),
            Err(SpecRefusal::GivenTwice {
                what: "grid cell",
                item: "full".into()
            })
        );
    }
}
