//! `RUN/metrics.jsonl`, the training log of `train` and `mer train`: one
//! [`MetricsRecord`] a line — `{"kind":"iter",…}` per iteration ([`IterRecord`]),
//! `{"kind":"val","epoch":0,…}` for the validation before training ([`ValLine`]),
//! `{"kind":"epoch",…}` per epoch with its validation ([`EpochRecord`]). The validation is a
//! depth network's ([`ValRecord`], `train`) or the PDA network's ([`PdaValRecord`], `mer
//! train`): the records are generic over it.
//!
//! Versions (each line carries its own): 1 (no `format_version`: every log written before
//! records were typed; an `iter` line may lack `lr`, an `epoch` line its timings or `val`),
//! 2 (the same fields plus `format_version`).

use std::path::Path;

use depthsense_metrics::Report;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::{from_value_at, legacy, nan_if_null, RecordError, Versioned};

/// The `format_version` of the lines `train` and `mer train` write.
pub const METRICS_VERSION: u32 = 2;

/// One line of metrics.jsonl; `V`: the validation record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum MetricsRecord<V> {
    Iter(IterRecord),
    Epoch(EpochRecord<V>),
    Val(ValLine<V>),
    /// A kind this build does not know (a newer writer's): left out by the readers.
    #[serde(other)]
    Other,
}

impl<V> Versioned for MetricsRecord<V> {
    const CURRENT: u32 = METRICS_VERSION;
    fn format_version(&self) -> u32 {
        match self {
            Self::Iter(r) => r.format_version,
            Self::Epoch(r) => r.format_version,
            Self::Val(r) => r.format_version,
            Self::Other => METRICS_VERSION,
        }
    }
}

/// One training iteration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IterRecord {
    #[serde(default = "legacy")]
    pub format_version: u32,
    /// 0-based epoch of the iteration.
    pub epoch: u64,
    /// Global iteration, 1-based.
    pub iteration: u64,
    #[serde(deserialize_with = "nan_if_null")]
    pub loss: f64,
    /// Its learning rate.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lr: Option<f64>,
}

impl IterRecord {
    pub fn new(epoch: u64, iteration: u64, loss: f64, lr: f64) -> Self {
        Self {
            format_version: METRICS_VERSION,
            epoch,
            iteration,
            loss,
            lr: Some(lr),
        }
    }
}

/// The end of an epoch: its mean training loss, timings and validation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(bound(deserialize = "V: Deserialize<'de>"))]
pub struct EpochRecord<V> {
    #[serde(default = "legacy")]
    pub format_version: u32,
    /// Epochs done (1-based).
    pub epoch: u64,
    /// Global iteration at its end.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub iteration: Option<u64>,
    /// Mean training loss of the epoch (`null`: no step).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_loss: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lr: Option<f64>,
    /// Images per second of the training steps of the invocation so far.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub images_per_s: Option<f64>,
    /// Images per second of this epoch's training steps.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub epoch_images_per_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_seconds: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub val_seconds: Option<f64>,
    /// Wall seconds of the invocation so far.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seconds: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub val: Option<V>,
}

impl<V> EpochRecord<V> {
    /// An epoch's end with its validation, timings not recorded.
    pub fn new(epoch: u64, iteration: u64, train_loss: f64, val: V) -> Self {
        Self {
            format_version: METRICS_VERSION,
            epoch,
            iteration: Some(iteration),
            train_loss: Some(train_loss),
            lr: None,
            images_per_s: None,
            epoch_images_per_s: None,
            train_seconds: None,
            val_seconds: None,
            seconds: None,
            val: Some(val),
        }
    }
}

/// A validation outside an epoch's end: the one before training (epoch 0, iteration 0).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValLine<V> {
    #[serde(default = "legacy")]
    pub format_version: u32,
    pub epoch: u64,
    pub iteration: u64,
    pub val: V,
}

impl<V> ValLine<V> {
    pub fn new(epoch: u64, iteration: u64, val: V) -> Self {
        Self {
            format_version: METRICS_VERSION,
            epoch,
            iteration,
            val,
        }
    }
}

impl<V: Serialize> MetricsRecord<V> {
    /// The line as JSON (keys sorted, as the log was written before records were typed).
    pub fn to_value(&self) -> Result<Value, serde_json::Error> {
        serde_json::to_value(self)
    }
}

impl<V> MetricsRecord<V> {
    /// The global iteration of the line, when it has one.
    pub fn iteration(&self) -> Option<u64> {
        match self {
            Self::Iter(r) => Some(r.iteration),
            Self::Epoch(r) => r.iteration,
            Self::Val(r) => Some(r.iteration),
            Self::Other => None,
        }
    }

    /// The validation of an `epoch` or `val` line: (epoch, iteration when recorded, record).
    pub fn validation(&self) -> Option<(u64, Option<u64>, &V)> {
        match self {
            Self::Epoch(r) => Some((r.epoch, r.iteration, r.val.as_ref()?)),
            Self::Val(r) => Some((r.epoch, Some(r.iteration), &r.val)),
            _ => None,
        }
    }
}

/// One validation of a depth network (`train`), SPEC §9 metrics of the headline row.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValRecord {
    pub epoch: u64,
    pub iteration: u64,
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub mae: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub abs_rel: f64,
    #[serde(deserialize_with = "nan_if_null")]
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
    /// The headline row of `r` (zeros without one).
    pub fn from_report(epoch: u64, iteration: u64, r: &Report) -> Self {
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

/// One validation of the PDA network (`mer train`): the associations over every labelled
/// (radar pixel, neighbour) pair.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PdaValRecord {
    pub epoch: u64,
    pub iteration: u64,
    /// Class-balanced BCE, mean over validation batches.
    #[serde(deserialize_with = "nan_if_null")]
    pub loss: f64,
    /// At confidence > 0.5.
    #[serde(deserialize_with = "nan_if_null")]
    pub precision: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub recall: f64,
    /// ROC area under the curve (ties counted ½).
    #[serde(deserialize_with = "nan_if_null")]
    pub auc: f64,
    pub pairs: u64,
    pub positives: u64,
}

/// The progress line of a validation.
impl std::fmt::Display for PdaValRecord {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "loss {:.4}, AUC {:.4}, precision {:.3}, recall {:.3} on {} pairs ({} positive)",
            self.loss, self.auc, self.precision, self.recall, self.pairs, self.positives
        )
    }
}

/// What to do with a line of metrics.jsonl that is not JSON.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BadLine {
    /// An error naming the file (a run this process wrote must read back whole).
    Fail,
    /// Left out (a run killed mid-write may end in half a line).
    Skip,
}

/// The JSON lines of a metrics.jsonl text with their 1-based line numbers (`path`: named in
/// errors; a line that is not JSON fails or is left out as `bad` says).
pub fn json_lines(
    text: &str,
    path: &Path,
    bad: BadLine,
) -> Result<Vec<(usize, Value)>, RecordError> {
    let mut out = vec![];
    for (i, l) in text.lines().enumerate() {
        if l.trim().is_empty() {
            continue;
        }
        match (serde_json::from_str::<Value>(l), bad) {
            (Ok(v), _) => out.push((i + 1, v)),
            (Err(_), BadLine::Skip) => {}
            (Err(e), BadLine::Fail) => {
                return Err(RecordError {
                    path: path.to_path_buf(),
                    line: Some(i + 1),
                    field: None,
                    problem: format!("not valid JSON: {e}"),
                })
            }
        }
    }
    Ok(out)
}

/// The JSON lines as records: a line of a known kind that lacks a field (or has one of the
/// wrong type, or a newer version) is an error naming the file, the line and the field.
pub fn typed<V: DeserializeOwned>(
    lines: Vec<(usize, Value)>,
    path: &Path,
) -> Result<Vec<MetricsRecord<V>>, RecordError> {
    lines
        .into_iter()
        .map(|(n, v)| parse_line(v, path, n))
        .collect()
}

/// One line's JSON as its record, by its `kind` (read here rather than by serde's tagged enum,
/// which loses the path of a missing field: `val.rmse`, not `rmse`).
pub fn parse_line<V: DeserializeOwned>(
    v: Value,
    path: &Path,
    line: usize,
) -> Result<MetricsRecord<V>, RecordError> {
    let kind = v.get("kind").and_then(Value::as_str).map(str::to_string);
    let strip = |mut v: Value| {
        if let Some(o) = v.as_object_mut() {
            o.remove("kind");
        }
        v
    };
    let at = Some(line);
    let record = match kind.as_deref() {
        Some("iter") => MetricsRecord::Iter(from_value_at(strip(v), path, at)?),
        Some("epoch") => MetricsRecord::Epoch(from_value_at(strip(v), path, at)?),
        Some("val") => MetricsRecord::Val(from_value_at(strip(v), path, at)?),
        Some(_) => MetricsRecord::Other,
        None => {
            return Err(RecordError {
                path: path.to_path_buf(),
                line: at,
                field: Some("kind".into()),
                problem: "missing".into(),
            })
        }
    };
    let version = record.format_version();
    if version > METRICS_VERSION {
        return Err(RecordError {
            path: path.to_path_buf(),
            line: at,
            field: Some("format_version".into()),
            problem: format!(
                "{version} is newer than this depthsense reads ({METRICS_VERSION}): update \
                 depthsense"
            ),
        });
    }
    Ok(record)
}

/// Read metrics.jsonl whole: the records of its lines.
pub fn read<V: DeserializeOwned>(
    path: &Path,
    bad: BadLine,
) -> Result<Vec<MetricsRecord<V>>, RecordError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| RecordError::new(path, format!("cannot read: {e}")))?;
    typed(json_lines(&text, path, bad)?, path)
}

/// Whether the validations of these lines are the PDA network's (`mer train`: an `auc`).
pub fn holds_pda(lines: &[(usize, Value)]) -> bool {
    lines
        .iter()
        .any(|(_, v)| v.get("val").and_then(|x| x.get("auc")).is_some())
}
