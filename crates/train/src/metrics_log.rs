//! RUN/metrics.jsonl, the training log (`train` and `mer train` write the same format):
//! `{"kind":"iter",…}` per iteration, `{"kind":"epoch",…}` per epoch with its validation
//! record. One writer ([`append_jsonl`]), one line parser and one reader ([`read_log`]; a line
//! that is not JSON fails or is skipped, [`BadLine`]), the resume cut ([`truncate_metrics`]) and
//! the curves drawn from it ([`write_curves`]).

use std::io::Write;
use std::path::Path;

use depthsense_base::fsutil::write_atomic;
use depthsense_metrics::Report;
use serde::{Deserialize, Serialize};

use depthsense_infer::NetError;

/// One validation result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValRecord {
    pub epoch: u64,
    pub iteration: u64,
    pub rmse: f64,
    pub mae: f64,
    pub abs_rel: f64,
    pub delta1: f64,
    pub n_images: u64,
    pub n_pixels: u64,
}

/// The progress line of a validation: `RMSE 9.412 m, MAE 4.120 m, AbsRel 0.213, δ1 0.712 on
/// 16 images`.
impl std::fmt::Display for ValRecord {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "RMSE {:.3} m, MAE {:.3} m, AbsRel {:.3}, δ1 {:.3} on {} images",
            self.rmse, self.mae, self.abs_rel, self.delta1, self.n_images
        )
    }
}

impl ValRecord {
    pub(crate) fn from_report(epoch: u64, iteration: u64, r: &Report) -> Self {
        let row = r.headline().cloned();
        let m = row.as_ref().map(|r| r.metrics).unwrap_or_default();
        Self {
            epoch,
            iteration,
            rmse: m.rmse,
            mae: m.mae,
            abs_rel: m.abs_rel,
            delta1: m.delta1,
            n_images: row.as_ref().map_or(0, |r| r.n_images),
            n_pixels: row.as_ref().map_or(0, |r| r.n_pixels),
        }
    }
}

/// Append one record (a JSON line).
pub fn append_jsonl(path: &Path, v: &serde_json::Value) -> Result<(), NetError> {
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| NetError::io(path, e))?;
    writeln!(f, "{v}").map_err(|e| NetError::io(path, e))
}

/// Keep only the records of metrics.jsonl up to `iteration` (resume after an interruption).
pub fn truncate_metrics(path: &Path, iteration: u64) -> Result<(), NetError> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(());
    };
    let kept: String = records(&text)
        .filter(|(_, v)| {
            v.as_ref()
                .ok()
                .and_then(|v| v.get("iteration").and_then(|i| i.as_u64()))
                .is_some_and(|i| i <= iteration)
        })
        .map(|(l, _)| format!("{l}\n"))
        .collect();
    write_atomic(path, kept.as_bytes()).map_err(|e| NetError::io(path, e))
}

/// (global iteration, loss) pairs of a run.
pub type LossCurve = Vec<(u64, f64)>;

/// What to do with a line of metrics.jsonl that is not JSON.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BadLine {
    /// An error naming the file (`train`, `--resume`, the curves, the demo: a run this process
    /// wrote must read back whole).
    Fail,
    /// Skipped (an experiment asking whether a run it finds on disk ended: a run killed
    /// mid-write may end in half a line).
    Skip,
}

/// The end of an epoch as metrics.jsonl records it (`{"kind":"epoch",…}`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpochEnd {
    pub epoch: Option<u64>,
    /// Training time of the invocation so far.
    pub seconds: Option<f64>,
}

/// Everything read back from metrics.jsonl.
#[derive(Debug, Clone, Default)]
pub struct MetricsLog {
    pub losses: LossCurve,
    /// Validation records (`"kind":"epoch"` or `"val"` with a `val` object).
    pub val: Vec<ValRecord>,
    pub epoch_ends: Vec<EpochEnd>,
}

/// Every line of metrics.jsonl with its JSON (the one line parser of the log).
fn records(text: &str) -> impl Iterator<Item = (&str, serde_json::Result<serde_json::Value>)> {
    text.lines()
        .map(|l| (l, serde_json::from_str::<serde_json::Value>(l)))
}

/// Read metrics.jsonl: the one reader of the log.
pub fn read_log(path: &Path, bad: BadLine) -> Result<MetricsLog, NetError> {
    let text = std::fs::read_to_string(path).map_err(|e| NetError::io(path, e))?;
    let mut log = MetricsLog::default();
    for (_, v) in records(&text) {
        let v = match (v, bad) {
            (Ok(v), _) => v,
            (Err(_), BadLine::Skip) => continue,
            (Err(e), BadLine::Fail) => {
                return Err(NetError::Parse {
                    path: path.to_path_buf(),
                    reason: e.to_string(),
                })
            }
        };
        match v.get("kind").and_then(|k| k.as_str()) {
            Some("iter") => log.losses.push((
                v["iteration"].as_u64().unwrap_or(0),
                v["loss"].as_f64().unwrap_or(f64::NAN),
            )),
            Some(kind @ ("epoch" | "val")) => {
                if let Ok(r) = serde_json::from_value::<ValRecord>(v["val"].clone()) {
                    log.val.push(r);
                }
                if kind == "epoch" {
                    log.epoch_ends.push(EpochEnd {
                        epoch: v.get("epoch").and_then(|e| e.as_u64()),
                        seconds: v.get("seconds").and_then(|s| s.as_f64()),
                    });
                }
            }
            _ => {}
        }
    }
    Ok(log)
}

/// Read the loss curve and the validation records back from metrics.jsonl (a line that is not
/// JSON is an error).
pub fn read_metrics(path: &Path) -> Result<(LossCurve, Vec<ValRecord>), NetError> {
    let log = read_log(path, BadLine::Fail)?;
    Ok((log.losses, log.val))
}

/// (sum, count) of the losses logged for iterations `after` < i ≤ `upto`: an epoch's running
/// loss before a resume inside it, so that its mean counts every step as in an uninterrupted
/// run. An unreadable log counts nothing.
pub fn logged_loss_sum(path: &Path, after: u64, upto: u64) -> (f64, usize) {
    let losses = read_metrics(path).map(|(l, _)| l).unwrap_or_default();
    losses
        .iter()
        .filter(|(i, _)| *i > after && *i <= upto)
        .fold((0.0, 0), |(sum, n), (_, l)| (sum + l, n + 1))
}

/// Render RUN/curves.png from RUN/metrics.jsonl.
pub fn write_curves(metrics_path: &Path, png: &Path) -> Result<(), NetError> {
    let (losses, val) = read_metrics(metrics_path)?;
    let val_pts: Vec<(u64, f64)> = val.iter().map(|v| (v.iteration, v.rmse)).collect();
    let bytes = depthsense_viz::plot::curves_png(
        &[("train loss", &losses)],
        &[("val RMSE (m)", &val_pts)],
    )?;
    write_atomic(png, &bytes).map_err(|e| NetError::io(png, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    const LOG: &str = concat!(
        r#"{"kind":"iter","iteration":1,"loss":2.5}"#,
        "\n",
        r#"{"kind":"epoch","epoch":1,"seconds":3.0,"val":{"epoch":1,"iteration":1,"rmse":4.0,"mae":1.0,"abs_rel":0.5,"delta1":0.25,"n_images":2,"n_pixels":9}}"#,
        "\n",
        r#"{"kind":"iter","iteration":2,"loss":1.5}"#,
        "\n",
        r#"{"kind":"epoch","epoch":2,"seconds":2.0}"#,
        "\n",
        r#"{"kind":"iter","iteration":3,"lo"#,
    );

    #[test]
    fn logged_losses_of_an_interval_are_summed() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("metrics.jsonl");
        let lines: Vec<String> = (1..=6)
            .map(|i| format!(r#"{{"kind":"iter","epoch":0,"iteration":{i},"loss":{i}.0}}"#))
            .collect();
        std::fs::write(&p, lines.join("\n")).unwrap();
        assert_eq!(logged_loss_sum(&p, 2, 5), (3.0 + 4.0 + 5.0, 3));
        assert_eq!(logged_loss_sum(&p, 6, 9), (0.0, 0));
        assert_eq!(logged_loss_sum(&d.path().join("none"), 0, 9), (0.0, 0));
    }

    #[test]
    fn a_bad_line_fails_or_is_skipped_as_asked() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("metrics.jsonl");
        std::fs::write(&p, LOG).unwrap();
        let err = read_log(&p, BadLine::Fail).unwrap_err().to_string();
        assert!(err.contains(&p.display().to_string()), "{err}");
        let log = read_log(&p, BadLine::Skip).unwrap();
        assert_eq!(log.losses, vec![(1, 2.5), (2, 1.5)]);
        assert_eq!(log.val.len(), 1);
        assert_eq!((log.val[0].rmse, log.val[0].n_pixels), (4.0, 9));
        let ends: Vec<_> = log
            .epoch_ends
            .iter()
            .map(|e| (e.epoch, e.seconds))
            .collect();
        assert_eq!(ends, vec![(Some(1), Some(3.0)), (Some(2), Some(2.0))]);
        assert!(read_log(&d.path().join("absent"), BadLine::Skip).is_err());
    }

    #[test]
    fn truncation_keeps_the_records_up_to_the_iteration() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("metrics.jsonl");
        std::fs::write(&p, LOG).unwrap();
        truncate_metrics(&p, 1).unwrap();
        let (losses, val) = read_metrics(&p).unwrap();
        assert_eq!(losses, vec![(1, 2.5)]);
        assert!(
            val.is_empty(),
            "the epoch line carries no top-level iteration"
        );
        assert_eq!(std::fs::read_to_string(&p).unwrap().lines().count(), 1);
    }
}
