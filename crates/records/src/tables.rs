//! `tables.json`, what `eval` (and the demo) write beside `tables.md` and `tables.csv`: every
//! row of every model's report (`"models"`: name and `metrics::Report`), the rendered tables
//! (`"tables"`), the command line and the section's document.
//!
//! Versions: 1 (no `format_version`: every evaluation written before records were typed), 2
//! (the same fields plus `format_version`).

use std::path::Path;

use depthsense_metrics::doc::Doc;
use depthsense_metrics::Report;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::{convert, legacy, nan_if_null, RecordError, Rest, Versioned};

/// The `format_version` `eval` writes in tables.json.
pub const TABLES_VERSION: u32 = 2;

/// tables.json.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TablesRecord {
    #[serde(default = "legacy")]
    pub format_version: u32,
    pub models: Vec<ModelTables>,
    /// The invocation (`null`: not recorded).
    #[serde(default)]
    pub command_line: Option<String>,
    /// The paper's tables as rendered (`metrics::tables::all_tables`; no reader uses them).
    #[serde(default, skip_serializing_if = "Value::is_null")]
    pub tables: Value,
    /// The section's document (`metrics::doc::Doc`; absent before documents were recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub document: Option<Value>,
}

impl Versioned for TablesRecord {
    const CURRENT: u32 = TABLES_VERSION;
    fn format_version(&self) -> u32 {
        self.format_version
    }
}

/// One evaluated model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelTables {
    pub name: String,
    pub report: ReportRows,
}

/// A model's report (`metrics::Report`): its rows typed, `config` and `images_seen` as
/// written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReportRows {
    pub rows: Vec<ReportRow>,
    #[serde(flatten)]
    pub rest: Rest,
}

/// One row of a report (`metrics::Row`): a condition × region × cap.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReportRow {
    pub condition: String,
    pub region: String,
    pub cap_m: f64,
    pub n_images: u64,
    pub metrics: HeadlineMetrics,
    /// `n_pixels`.
    #[serde(flatten)]
    pub rest: Rest,
}

/// The metrics of a row the comparison shows (`metrics::Metrics`: the others as written).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeadlineMetrics {
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub mae: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub abs_rel: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub delta1: f64,
    #[serde(flatten)]
    pub rest: Rest,
}

impl TablesRecord {
    /// The record of `models` (name, report), the rendered `tables`, the command line and the
    /// document; `path`: the file it is written to (named in an error).
    pub fn new(
        models: &[(&str, &Report)],
        tables: Value,
        command_line: Option<&str>,
        doc: &Doc,
        path: &Path,
    ) -> Result<Self, RecordError> {
        let models = models
            .iter()
            .map(|(name, r)| {
                Ok(ModelTables {
                    name: name.to_string(),
                    report: convert(r, path)?,
                })
            })
            .collect::<Result<_, RecordError>>()?;
        Ok(Self {
            format_version: TABLES_VERSION,
            models,
            command_line: command_line.map(str::to_string),
            tables,
            document: Some(
                serde_json::to_value(doc)
                    .map_err(|e| RecordError::new(path, format!("document: {e}")))?,
            ),
        })
    }
}

impl ModelTables {
    /// The headline row: combined conditions, full image, largest cap.
    pub fn headline(&self) -> Option<&ReportRow> {
        self.report
            .rows
            .iter()
            .filter(|r| r.condition == "combined" && r.region == "full")
            .max_by(|a, b| a.cap_m.total_cmp(&b.cap_m))
    }
}
