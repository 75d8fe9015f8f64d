//! `experiment perturb` (SPEC §10.7, calibration perturbation): one checkpoint evaluated with
//! the radar→camera extrinsic perturbed about each axis by each magnitude. The radar maps are
//! rebuilt from each sample's `radar_points.bin` by the rasterisation `prepare` uses
//! ([`depthsense_prep::radar_points`]), so magnitude 0 is the unperturbed evaluation bit for
//! bit. The perturbation ([`Perturbation`]): rotations (yaw about the camera's vertical axis,
//! pitch about its x axis, roll about its optical axis) turn the radar about its own position;
//! translations move it along the camera's x (right), y (down), z (forward). The sign is drawn
//! per sample from `(seed, sample token)` ([`super::failure`]), so each magnitude averages
//! both directions over the samples. Scoring is `eval`'s ([`depthsense_eval::evaluate::run_eval_loaded`]).

use std::path::Path;

use crate::{ExperimentError, SpecRefusal};
use depthsense_eval::evaluate::EvalOptions;
use depthsense_infer::NetError;
use depthsense_metrics::doc::Doc;
use depthsense_metrics::table::{csv_row, Align, MdTable};
use depthsense_prep::radar_points::{PerturbAxis, Perturbation};
use serde::{Deserialize, Serialize};

use super::runner::{row_values, run_bar, RowValues};
use depthsense_data::radar_failure::RadarFailure;

pub const PERTURB_MD: &str = "perturb.md";
pub const PERTURB_CSV: &str = "perturb.csv";
pub const PERTURB_JSON: &str = "perturb.json";
pub const PERTURB_PNG: &str = "perturb.png";

/// The grid of `experiment perturb`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PerturbOptions {
    /// Rotation magnitudes (degrees) for yaw, pitch, roll.
    pub rotate_deg: Vec<f64>,
    /// Translation magnitudes (metres) for x, y, z.
    pub translate_m: Vec<f64>,
    pub axes: Vec<PerturbAxis>,
}

impl Default for PerturbOptions {
    fn default() -> Self {
        PerturbOptions {
            rotate_deg: vec![0.5, 1.0, 2.0, 5.0],
            translate_m: vec![0.1, 0.25, 0.5],
            axes: PerturbAxis::ALL.to_vec(),
        }
    }
}

impl PerturbOptions {
    /// Every (axis, magnitude) to evaluate, axis by axis.
    pub fn grid(&self) -> Result<Vec<Perturbation>, SpecRefusal> {
        let mut out = vec![];
        for &axis in &self.axes {
            let mags = match axis.is_rotation() {
                true => &self.rotate_deg,
                false => &self.translate_m,
            };
            for &amount in mags {
                if !(amount.is_finite() && amount >= 0.0) {
                    return Err(SpecRefusal::NegativeMagnitude(amount));
                }
                out.push(Perturbation { axis, amount });
            }
        }
        if out.is_empty() {
            return Err(SpecRefusal::NothingGiven("perturbations"));
        }
        Ok(out)
    }
}

/// One evaluated perturbation (`axis` "none" = the baseline, magnitude 0).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PerturbRow {
    pub axis: String,
    pub magnitude: f64,
    /// "deg" or "m".
    pub unit: String,
    pub rows: Vec<RowValues>,
    pub report: depthsense_metrics::Report,
    pub seconds: f64,
}

impl PerturbRow {
    pub fn combined(&self) -> Option<&RowValues> {
        self.rows
            .iter()
            .find(|r| r.condition == "combined" && r.region == "full" && r.n_images > 0)
    }
}

/// Everything `experiment perturb` produced (= perturb.json).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PerturbResult {
    pub eval: EvalOptions,
    pub options: PerturbOptions,
    pub machine: super::Machine,
    pub baseline: PerturbRow,
    pub rows: Vec<PerturbRow>,
    pub command_line: Option<String>,
}

fn unit(axis: PerturbAxis) -> &'static str {
    if axis.is_rotation() {
        "deg"
    } else {
        "m"
    }
}

/// The evaluation `base` with its radar perturbed by `p`.
fn perturbed(base: &EvalOptions, p: Perturbation) -> EvalOptions {
    EvalOptions {
        failure: RadarFailure {
            perturb: Some(p),
            ..base.failure.clone()
        },
        ..base.clone()
    }
}

/// Evaluate `base` unperturbed (magnitude 0, through the same re-rasterisation) and under
/// every perturbation of `opts`; writes OUT/perturb.{md,csv,json,png}.
pub fn run_perturb(
    base: &EvalOptions,
    opts: &PerturbOptions,
    out: &Path,
    command_line: Option<String>,
    mp: &depthsense_progress::Board,
) -> Result<PerturbResult, ExperimentError> {
    let grid = opts.grid()?;
    let device = depthsense_model::device::parse_device(&base.device)?;
    let (loaded, _) = depthsense_eval::evaluate::load_model(
        &base.checkpoint,
        base.config.as_deref(),
        &base.set,
        device,
    )?;
    std::fs::create_dir_all(out).map_err(|e| NetError::io(out, e))?;
    let zero = Perturbation {
        axis: PerturbAxis::Yaw,
        amount: 0.0,
    };
    let total = mp.bar("perturbations");
    total.set_length(grid.len() as u64 + 1);
    let eval_one =
        |p: Perturbation, axis: &str, label: &str| -> Result<PerturbRow, ExperimentError> {
            let pb = run_bar(mp, label);
            let t = std::time::Instant::now();
            let o = perturbed(base, p);
            let report = depthsense_eval::evaluate::run_eval_loaded(&o, &loaded, &pb)?;
            pb.finish_and_clear();
            total.inc(1);
            Ok(PerturbRow {
                axis: axis.into(),
                magnitude: p.amount,
                unit: unit(p.axis).into(),
                rows: row_values(&report),
                report,
                seconds: t.elapsed().as_secs_f64(),
            })
        };
    let baseline = eval_one(zero, "none", "baseline")?;
    let mut rows = vec![];
    for p in grid {
        let label = format!("{} {}{}", p.axis.name(), p.amount, unit(p.axis));
        rows.push(eval_one(p, p.axis.name(), &label)?);
    }
    total.finish_and_clear();
    let r = PerturbResult {
        eval: base.clone(),
        options: opts.clone(),
        machine: super::Machine::describe(device),
        baseline,
        rows,
        command_line,
    };
    write_perturb(out, &r)?;
    Ok(r)
}

fn write_perturb(out: &Path, r: &PerturbResult) -> Result<(), ExperimentError> {
    let (json, md) = (out.join(PERTURB_JSON), out.join(PERTURB_MD));
    super::save_record(&json, &md, r, &perturb_document(r))?;
    super::save(&out.join(PERTURB_CSV), perturb_csv(r).as_bytes())?;
    super::save(&out.join(PERTURB_PNG), &perturb_png(r)?)
}

/// RMSE against magnitude, one line per axis (from the baseline at 0): rotations left,
/// translations right.
fn perturb_png(r: &PerturbResult) -> Result<Vec<u8>, ExperimentError> {
    let base = r.baseline.combined().map_or(f64::NAN, |x| x.rmse);
    let series = |rotation: bool| -> Vec<(&str, Vec<(f64, f64)>)> {
        PerturbAxis::ALL
            .into_iter()
            .filter(|a| a.is_rotation() == rotation)
            .filter(|a| r.rows.iter().any(|x| x.axis == a.name()))
            .map(|a| {
                let mut pts = vec![(0.0, base)];
                pts.extend(
                    r.rows
                        .iter()
                        .filter(|x| x.axis == a.name())
                        .map(|x| (x.magnitude, x.combined().map_or(f64::NAN, |c| c.rmse))),
                );
                (a.name(), pts)
            })
            .collect()
    };
    let (rot, tr) = (series(true), series(false));
    let mut panels = vec![];
    if !rot.is_empty() {
        panels.push(depthsense_viz::plot::LinePanel {
            title: "test RMSE vs radar rotation error",
            x_label: "rotation (degrees, random sign)",
            y_label: "RMSE (m)",
            series: &rot,
            error_bars: &[],
            log10_x: false,
        });
    }
    if !tr.is_empty() {
        panels.push(depthsense_viz::plot::LinePanel {
            title: "test RMSE vs radar translation error",
            x_label: "translation (m, random sign)",
            y_label: "RMSE (m)",
            series: &tr,
            error_bars: &[],
            log10_x: false,
        });
    }
    Ok(depthsense_viz::plot::line_charts_png(&panels)?)
}

fn md_row(t: &mut MdTable, x: &PerturbRow, base: Option<f64>) {
    let mut cells = vec![x.axis.to_string(), format!("{} {}", x.magnitude, x.unit)];
    cells.extend(RowValues::scenario_md_cells(x.combined(), base));
    t.row(&cells);
}

/// The perturbation table with its setup (perturb.md, and the report's section).
fn perturb_document(r: &PerturbResult) -> Doc {
    let e = &r.eval;
    let mut doc = Doc::new();
    doc.heading(1, "Calibration perturbation (SPEC §10.7)");
    doc.paragraph(format!(
        "Checkpoint `{}` on `{}` (split {}), cap {} m, full image, combined conditions; seed {} \
         (sign of each sample's perturbation). Rotations turn the radar about its own position \
         (yaw: camera vertical axis, pitch: camera x, roll: optical axis); translations move \
         it along camera x (right), y (down), z (forward). Each sample gets + or − the \
         magnitude at random. ΔRMSE is against the unperturbed row.",
        e.checkpoint.display(),
        e.data.display(),
        e.split,
        e.eval.main_cap(),
        e.seed
    ));
    let mut columns = vec![("axis", Align::Left), ("magnitude", Align::Right)];
    columns.extend(RowValues::SCENARIO_MD_COLUMNS);
    let mut t = MdTable::new(&columns);
    let base = r.baseline.combined().map(|x| x.rmse);
    md_row(&mut t, &r.baseline, base);
    for x in &r.rows {
        md_row(&mut t, x, base);
    }
    doc.table(t)
        .paragraph(format!("Machine: {}.", r.machine.line()))
        .command(r.command_line.as_deref());
    doc
}

fn perturb_csv(r: &PerturbResult) -> String {
    let mut s =
        String::from("axis,magnitude,unit,condition,n_images,rmse_m,mae_m,delta1,abs_rel\n");
    for x in std::iter::once(&r.baseline).chain(&r.rows) {
        for row in x.rows.iter().filter(|r| r.region == "full") {
            s.push_str(&csv_row(&[
                x.axis.to_string(),
                x.magnitude.to_string(),
                x.unit.to_string(),
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A negative or missing magnitude is refused with its value; no axis is nothing to do.
    #[test]
    fn the_grid_refuses_what_it_cannot_evaluate() {
        let o = PerturbOptions {
            rotate_deg: vec![1.0, -0.5],
            ..PerturbOptions::default()
        };
        assert_eq!(o.grid(), Err(SpecRefusal::NegativeMagnitude(-0.5)));
        let o = PerturbOptions {
            axes: vec![],
            ..PerturbOptions::default()
        };
        assert_eq!(o.grid(), Err(SpecRefusal::NothingGiven("perturbations")));
        assert_eq!(PerturbOptions::default().grid().map(|g| g.len()), Ok(21));
    }
}
