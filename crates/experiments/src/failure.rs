//! `experiment failure` (SPEC §10.8): one checkpoint evaluated under a list of failure
//! scenarios. The failures themselves ([`RadarFailure`]) are applied by the loader:
//! [`depthsense_data::radar_failure`].

use depthsense_metrics::doc::Doc;
use depthsense_metrics::table::{csv_quoted, csv_row, md_num, Align, MdTable};

use crate::runner::RowValues;
use serde::{Deserialize, Serialize};

use crate::{ExperimentError, SpecRefusal};
use depthsense_infer::NetError;

use depthsense_data::radar_failure::RadarFailure;

// ---------------------------------------------------------------------------------------
// `experiment failure`: one checkpoint evaluated under a list of failure scenarios.

/// One scenario: random point drop plus a [`RadarFailure`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scenario {
    pub name: String,
    pub radar_drop: f64,
    pub failure: RadarFailure,
}

/// Parse "none;radar-drop=0.5;drop-radars=RADAR_FRONT_LEFT+RADAR_FRONT_RIGHT;beyond=30;
/// clutter=20" (`;` between scenarios, `,` between settings of one scenario).
pub fn parse_scenarios(s: &str) -> Result<Vec<Scenario>, ExperimentError> {
    let mut out = vec![];
    for item in s.split(';').map(str::trim).filter(|x| !x.is_empty()) {
        let mut sc = Scenario {
            name: item.to_string(),
            radar_drop: 0.0,
            failure: RadarFailure::default(),
        };
        for kv in item.split(',').map(str::trim).filter(|x| *x != "none") {
            let bad = || SpecRefusal::UnreadableScenario {
                scenario: item.to_string(),
                setting: kv.to_string(),
            };
            let (k, v) = kv.split_once('=').ok_or_else(bad)?;
            match k {
                "radar-drop" => sc.radar_drop = v.parse().map_err(|_| bad())?,
                "drop-radars" => sc.failure.drop_radars = v.split('+').map(String::from).collect(),
                "beyond" => sc.failure.drop_beyond_m = Some(v.parse().map_err(|_| bad())?),
                "clutter" => sc.failure.clutter = v.parse().map_err(|_| bad())?,
                _ => return Err(bad().into()),
            }
        }
        sc.failure.validate()?;
        if !(0.0..=1.0).contains(&sc.radar_drop) {
            return Err(SpecRefusal::RadarDropOutOfRange {
                scenario: item.to_string(),
            }
            .into());
        }
        out.push(sc);
    }
    if out.is_empty() {
        return Err(SpecRefusal::NothingGiven("failure scenarios").into());
    }
    Ok(out)
}

/// One scenario's result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScenarioResult {
    pub scenario: Scenario,
    pub rows: Vec<super::runner::RowValues>,
    pub report: depthsense_metrics::Report,
    pub seconds: f64,
}

impl ScenarioResult {
    pub fn row(&self, condition: &str) -> Option<&super::runner::RowValues> {
        self.rows
            .iter()
            .find(|r| r.condition == condition && r.region == "full" && r.n_images > 0)
    }
}

/// Everything `experiment failure` produced (= failure.json).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FailureResult {
    pub eval: depthsense_eval::evaluate::EvalOptions,
    pub machine: super::Machine,
    pub results: Vec<ScenarioResult>,
    pub command_line: Option<String>,
}

pub const FAILURE_MD: &str = "failure.md";
pub const FAILURE_CSV: &str = "failure.csv";
pub const FAILURE_JSON: &str = "failure.json";
pub const FAILURE_PNG: &str = "failure.png";

/// Evaluate `base` (checkpoint, data, split, caps …) under every scenario; writes
/// OUT/failure.{md,csv,json,png}. Deterministic in `base.seed`.
pub fn run_failure(
    base: &depthsense_eval::evaluate::EvalOptions,
    scenarios: &[Scenario],
    out: &std::path::Path,
    command_line: Option<String>,
    mp: &depthsense_progress::Board,
) -> Result<FailureResult, ExperimentError> {
    let device = depthsense_model::device::parse_device(&base.device)?;
    let (loaded, _) = depthsense_eval::evaluate::load_model(
        &base.checkpoint,
        base.config.as_deref(),
        &base.set,
        device,
    )?;
    std::fs::create_dir_all(out).map_err(|e| NetError::io(out, e))?;
    let mut results = vec![];
    for sc in scenarios {
        let pb = super::runner::run_bar(mp, &sc.name);
        let t = std::time::Instant::now();
        let opts = depthsense_eval::evaluate::EvalOptions {
            radar_drop: sc.radar_drop,
            failure: sc.failure.clone(),
            ..base.clone()
        };
        let report = depthsense_eval::evaluate::run_eval_loaded(&opts, &loaded, &pb)?;
        pb.finish_and_clear();
        results.push(ScenarioResult {
            scenario: sc.clone(),
            rows: super::runner::row_values(&report),
            report,
            seconds: t.elapsed().as_secs_f64(),
        });
    }
    let r = FailureResult {
        eval: base.clone(),
        machine: super::Machine::describe(device),
        results,
        command_line,
    };
    write_failure(out, &r)?;
    Ok(r)
}

fn write_failure(out: &std::path::Path, r: &FailureResult) -> Result<(), ExperimentError> {
    let (json, md) = (out.join(FAILURE_JSON), out.join(FAILURE_MD));
    super::save_record(&json, &md, r, &failure_document(r))?;
    super::save(&out.join(FAILURE_CSV), failure_csv(r).as_bytes())?;
    let names: Vec<&str> = r.results.iter().map(|x| x.scenario.name.as_str()).collect();
    let metric = |f: fn(&super::runner::RowValues) -> f64| -> Vec<f64> {
        r.results
            .iter()
            .map(|x| x.row("combined").map_or(f64::NAN, f))
            .collect()
    };
    let (rm, d1) = (metric(|x| x.rmse), metric(|x| x.delta1));
    let nan = vec![f64::NAN; names.len()];
    let png = depthsense_viz::plot::bar_charts_png(&[
        depthsense_viz::plot::BarPanel {
            title: "test RMSE (m) under radar failure",
            labels: &names,
            means: &rm,
            stds: &nan,
            y_label: "RMSE (m)",
        },
        depthsense_viz::plot::BarPanel {
            title: "test δ1 under radar failure",
            labels: &names,
            means: &d1,
            stds: &nan,
            y_label: "δ1",
        },
    ])?;
    super::save(&out.join(FAILURE_PNG), &png)
}

/// The scenario table with its setup (failure.md, and the report's section).
fn failure_document(r: &FailureResult) -> Doc {
    let e = &r.eval;
    let mut doc = Doc::new();
    doc.heading(1, "Sensor failure (SPEC §10.8)");
    doc.paragraph(format!(
        "Checkpoint `{}` on `{}` (split {}), cap {} m, full image; seed {} (radar drop and \
         clutter draws). Scenario rules: docs/guide/experiments.md, \"Sensor failure\". ΔRMSE is against the \
         first scenario.",
        e.checkpoint.display(),
        e.data.display(),
        e.split,
        e.eval.main_cap(),
        e.seed
    ));
    let mut columns = vec![("scenario", Align::Left)];
    columns.extend(RowValues::SCENARIO_MD_COLUMNS);
    columns.extend([
        ("RMSE day", Align::Right),
        ("RMSE night", Align::Right),
        ("RMSE rain", Align::Right),
    ]);
    let mut t = MdTable::new(&columns);
    let base = r
        .results
        .first()
        .and_then(|x| x.row("combined"))
        .map(|x| x.rmse);
    for x in &r.results {
        let cond = |n: &str| md_num(x.row(n).map(|r| r.rmse), 3);
        let mut cells = vec![x.scenario.name.clone()];
        cells.extend(RowValues::scenario_md_cells(x.row("combined"), base));
        cells.extend([cond("day"), cond("night"), cond("rain")]);
        t.row(&cells);
    }
    doc.table(t)
        .paragraph(format!("Machine: {}.", r.machine.line()))
        .command(r.command_line.as_deref());
    doc
}

fn failure_csv(r: &FailureResult) -> String {
    let mut s = String::from("scenario,condition,n_images,rmse_m,mae_m,delta1,abs_rel\n");
    for x in &r.results {
        for row in x.rows.iter().filter(|r| r.region == "full") {
            s.push_str(&csv_row(&[
                csv_quoted(&x.scenario.name),
                row.condition.to_string(),
                row.n_images.to_string(),
                format!("{:.6}", row.rmse),
                format!("{:.6}", row.mae),
                format!("{:.6}", row.delta1),
                format!("{:.6}", row.abs_rel),
            ]));
        }
    }
    s
}
