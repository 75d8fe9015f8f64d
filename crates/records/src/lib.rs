//! depthsense-records (layer 2, ARCHITECTURE.md) — the records a run folder and an output hold,
//! as serde types shared by the commands that write them and the report that reads them back
//! (no libtorch):
//!
//! | file | type | written by | version |
//! |---|---|---|---|
//! | `RUN/config.json` | [`run_config::RunConfig`] (`train`: [`run_config::TrainRunConfig`], `mer train`: [`run_config::MerRunConfig`]) | `train`, `mer train` | [`run_config::RUN_CONFIG_VERSION`] |
//! | `RUN/metrics.jsonl` | one [`metrics_log::MetricsRecord`] a line | `train`, `mer train` | [`metrics_log::METRICS_VERSION`] |
//! | `tables.json` | [`tables::TablesRecord`] | `eval`, the demo | [`tables::TABLES_VERSION`] |
//! | `FILE.json` beside an export | [`sidecar::SidecarRecord`] | `export` | [`sidecar::SIDECAR_FORMAT`] |
//!
//! Every record carries its `format_version`; one written before records carried it reads as
//! [`LEGACY_VERSION`], and a version newer than this build knows is refused. The fields a reader
//! uses are typed (a field a record lacks is an error naming the file and the field:
//! `runs/x/config.json: field "train.epochs": missing`); what no reader uses is kept as written
//! (`rest`), so that a record reads back to the same JSON.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Deserializer, Serialize};
use serde_json::Value;

pub mod metrics_log;
pub mod run_config;
pub mod sidecar;
pub mod tables;

/// The `format_version` of a record written before records carried one.
pub const LEGACY_VERSION: u32 = 1;

pub(crate) fn legacy() -> u32 {
    LEGACY_VERSION
}

/// The fields of a record that no reader uses, as written.
pub type Rest = serde_json::Map<String, Value>;

/// A record that cannot be read (or written): its file, the line of a JSON-lines file, the
/// field and the problem.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: {}", self.place(), self.detail())]
pub struct RecordError {
    pub path: PathBuf,
    /// 1-based line of a JSON-lines file.
    pub line: Option<usize>,
    /// Dotted path of the field (`train.epochs`, `models[0].report.rows[1].cap_m`); `None`
    /// when the problem is the whole file (unreadable, not JSON).
    pub field: Option<String>,
    pub problem: String,
}

impl RecordError {
    pub fn new(path: &Path, problem: impl Into<String>) -> Self {
        Self {
            path: path.to_path_buf(),
            line: None,
            field: None,
            problem: problem.into(),
        }
    }

    /// The file (and line) of the record.
    pub fn place(&self) -> String {
        match self.line {
            Some(l) => format!("{} line {l}", self.path.display()),
            None => self.path.display().to_string(),
        }
    }

    /// What is wrong, without the file: `field "train.epochs": missing`.
    pub fn detail(&self) -> String {
        match &self.field {
            Some(f) => format!("field \"{f}\": {}", self.problem),
            None => self.problem.clone(),
        }
    }

    /// The detail with the line of a JSON-lines file (the file named elsewhere):
    /// `line 3: field "val.rmse": missing`.
    pub fn reason(&self) -> String {
        match self.line {
            Some(l) => format!("line {l}: {}", self.detail()),
            None => self.detail(),
        }
    }
}

/// A record type: its current `format_version` and the one a value carries.
pub trait Versioned {
    /// What this build writes and the newest it reads.
    const CURRENT: u32;
    fn format_version(&self) -> u32;
}

/// `value` as a `T`, an error naming `path` (and `line`), the field and the problem.
pub fn from_value_at<T: DeserializeOwned>(
    value: Value,
    path: &Path,
    line: Option<usize>,
) -> Result<T, RecordError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let at = e.path().to_string();
        let msg = e.inner().to_string();
        let (field, problem) = match missing_field(&msg) {
            Some(name) if at == "." => (Some(name.to_string()), "missing".to_string()),
            Some(name) => (Some(format!("{at}.{name}")), "missing".to_string()),
            None => ((at != ".").then_some(at), msg),
        };
        RecordError {
            path: path.to_path_buf(),
            line,
            field,
            problem,
        }
    })
}

/// The name in serde's "missing field `x`".
fn missing_field(msg: &str) -> Option<&str> {
    msg.strip_prefix("missing field `")?.split('`').next()
}

/// A record of `path` read whole: not readable, not JSON, a field missing or of the wrong type,
/// or a `format_version` newer than this build, each an error naming the file (and field).
pub fn read_json<T: DeserializeOwned + Versioned>(path: &Path) -> Result<T, RecordError> {
    let value = read_value(path)?;
    checked(value, path, None)
}

/// The JSON of `path` (any JSON).
pub fn read_value(path: &Path) -> Result<Value, RecordError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| RecordError::new(path, format!("cannot read: {e}")))?;
    serde_json::from_str(&text).map_err(|e| RecordError::new(path, format!("not valid JSON: {e}")))
}

/// [`from_value_at`] and the version check.
pub fn checked<T: DeserializeOwned + Versioned>(
    value: Value,
    path: &Path,
    line: Option<usize>,
) -> Result<T, RecordError> {
    let r: T = from_value_at(value, path, line)?;
    if r.format_version() > T::CURRENT {
        return Err(RecordError {
            path: path.to_path_buf(),
            line,
            field: Some("format_version".into()),
            problem: format!(
                "{} is newer than this depthsense reads ({}): update depthsense",
                r.format_version(),
                T::CURRENT
            ),
        });
    }
    Ok(r)
}

/// A writer's value (`TrainOptions`, a `Report`, a `Sidecar`) as the record type `T` that holds
/// it: the same JSON, checked to carry every field the readers use. `path`: the file it goes to
/// (named in the error: a writer whose value lacks a field the report reads).
pub fn convert<T: DeserializeOwned>(full: &impl Serialize, path: &Path) -> Result<T, RecordError> {
    let value = serde_json::to_value(full)
        .map_err(|e| RecordError::new(path, format!("cannot be written as JSON: {e}")))?;
    from_value_at(value, path, None)
}

/// A record as pretty JSON, its keys sorted (the order `serde_json::json!` gave the files
/// written before records were typed).
pub fn to_json_pretty(record: &impl Serialize) -> Result<String, serde_json::Error> {
    serde_json::to_string_pretty(&serde_json::to_value(record)?)
}

/// A record as one JSON line (keys sorted), without the newline.
pub fn to_json_line(record: &impl Serialize) -> Result<String, serde_json::Error> {
    serde_json::to_string(&serde_json::to_value(record)?)
}

/// A float written as `null` (JSON has no NaN: serde_json writes a non-finite number as `null`)
/// reads back as NaN.
pub(crate) fn nan_if_null<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// A number as the JSON shows it (`0.002`, `1.0`, `7`): how the report printed values it read
/// from JSON before they were typed.
pub fn json_number(x: impl Into<Value>) -> String {
    x.into().to_string()
}
