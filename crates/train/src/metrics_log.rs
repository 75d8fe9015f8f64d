//! RUN/metrics.jsonl, the training log (`train` and `mer train` write the same format; its
//! records are `depthsense_records::metrics_log`'s, shared with the report):
//! `{"kind":"iter",…}` per iteration, `{"kind":"epoch",…}` per epoch with its validation
//! record. One writer ([`append_jsonl`], which `crate::run_folder::RunFolder` writes through),
//! one reader ([`read_log`]; a line
//! that is not JSON fails or is skipped, [`BadLine`]; a line that lacks a field is an error
//! naming the file, the line and the field), the resume cut ([`truncate_metrics`]) and the
//! curves drawn from it ([`write_curves`]).

use std::io::Write;
use std::path::Path;

use depthsense_base::fsutil::write_atomic;
use depthsense_records::metrics_log::{json_lines, typed, MetricsRecord};
use depthsense_records::RecordError;

use depthsense_infer::NetError;

pub use depthsense_records::metrics_log::{
    BadLine, EpochRecord, IterRecord, ValLine, ValRecord, METRICS_VERSION,
};

fn record_error(e: RecordError) -> NetError {
    NetError::Parse {
        path: e.path.clone(),
        reason: e.reason(),
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

/// Every line of metrics.jsonl with its JSON (the resume cut's line parser).
fn records(text: &str) -> impl Iterator<Item = (&str, serde_json::Result<serde_json::Value>)> {
    text.lines()
        .map(|l| (l, serde_json::from_str::<serde_json::Value>(l)))
}

/// Read metrics.jsonl: the one reader of the log. A validation that is not a depth network's
/// (`mer train`'s PDA records) is not in `val`.
pub fn read_log(path: &Path, bad: BadLine) -> Result<MetricsLog, NetError> {
    let text = std::fs::read_to_string(path).map_err(|e| NetError::io(path, e))?;
    let lines = json_lines(&text, path, bad).map_err(record_error)?;
    let records = match typed::<serde_json::Value>(lines.clone(), path) {
        Ok(r) => r,
        // A run killed mid-write, read leniently: the lines that read.
        Err(_) if bad == BadLine::Skip => lines
            .into_iter()
            .filter_map(|(n, v)| typed(vec![(n, v)], path).ok()?.pop())
            .collect(),
        Err(e) => return Err(record_error(e)),
    };
    let mut log = MetricsLog::default();
    for r in records {
        if let Some((_, _, v)) = r.validation() {
            if let Ok(v) = serde_json::from_value::<ValRecord>(v.clone()) {
                log.val.push(v);
            }
        }
        match r {
            MetricsRecord::Iter(i) => log.losses.push((i.iteration, i.loss)),
            MetricsRecord::Epoch(e) => log.epoch_ends.push(EpochEnd {
                epoch: Some(e.epoch),
                seconds: e.seconds,
            }),
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
        r#"{"kind":"iter","epoch":0,"iteration":1,"loss":2.5}"#,
        "\n",
        r#"{"kind":"epoch","epoch":1,"seconds":3.0,"val":{"epoch":1,"iteration":1,"rmse":4.0,"mae":1.0,"abs_rel":0.5,"delta1":0.25,"n_images":2,"n_pixels":9}}"#,
        "\n",
        r#"{"kind":"iter","epoch":1,"iteration":2,"loss":1.5}"#,
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

    /// `train`'s options and network convert into config.json's record (the fields the report
    /// shows are there, under the names it reads).
    #[test]
    fn the_options_convert_into_the_config_record() {
        use depthsense_records::run_config::{ModelSummary, RunOptions};
        let o = crate::trainer::TrainOptions::default();
        let p = Path::new("config.json");
        let t: RunOptions = depthsense_records::convert(&o, p).unwrap();
        assert_eq!((t.epochs, t.batch_size, t.lr), (40, 8, 1e-3));
        assert_eq!(t.rest["momentum"], serde_json::json!(0.9));
        let m: ModelSummary = depthsense_records::convert(&o.model, p).unwrap();
        assert_eq!(m.fusion_words(), "late fusion + attention");
    }
}
