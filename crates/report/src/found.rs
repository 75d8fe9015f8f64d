//! What discovery finds, shared by the finders (`discover`) and the sections they build
//! (`runs`): an output found ([`Found`]) with its images, the rows of the model comparison
//! ([`ModelRow`]), and the JSON accessors both read records with.

use std::path::{Path, PathBuf};

use depthsense_metrics::doc::Doc;
use serde_json::Value;

use super::{FigureGrid, Kind};

/// An image to embed: source file, caption, and whether it is a grid tile.
#[derive(Debug, Clone)]
pub struct ImageSource {
    pub path: PathBuf,
    pub caption: String,
    pub tile: bool,
}

/// One output found, before its images are read.
#[derive(Debug, Clone)]
pub struct Found {
    pub kind: Kind,
    pub dir: PathBuf,
    pub files: Vec<PathBuf>,
    pub command_line: Option<String>,
    pub inputs: Vec<(String, String)>,
    /// What the section says: built from the JSON, or the writer's Markdown as one block.
    pub doc: Doc,
    pub images: Vec<ImageSource>,
    /// Cells index `images`.
    pub grid: Option<FigureGrid>,
    /// Models this output evaluated or trained, for the comparison table.
    pub models: Vec<ModelRow>,
}

/// Which scenes a row of the comparison was scored on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Split {
    /// Test scenes, never used for a choice: these rows compare models.
    Test,
    /// Validation scenes: the best epoch of a training run (they chose the checkpoint).
    Validation,
}

/// One model of the comparison tables.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelRow {
    pub name: String,
    pub split: Split,
    /// Where the row comes from: `eval`, `demo`, `ablation`, …, or for a validation row the
    /// epoch it picked (`best epoch (3)`).
    pub rows: String,
    pub dir: PathBuf,
    /// The prepared data it was scored on, when recorded.
    pub data: Option<String>,
    /// The depth cap of the row (m).
    pub cap_m: Option<f64>,
    /// Seeds behind the values (an experiment's arm: its mean over seeds; a checkpoint: 1).
    pub seeds: Option<usize>,
    /// A training run that stopped before its last epoch: the mark shown beside it.
    pub unfinished: Option<String>,
    pub images: Option<u64>,
    pub rmse_m: Option<f64>,
    pub mae_m: Option<f64>,
    pub abs_rel: Option<f64>,
    pub delta1: Option<f64>,
}

impl ModelRow {
    /// The four metrics of the tables, in column order.
    pub(crate) fn metrics(&self) -> [Option<f64>; 4] {
        [self.rmse_m, self.mae_m, self.abs_rel, self.delta1]
    }

    /// The test set a row was scored on: rows compare only with rows of the same data, cap and
    /// images.
    pub(crate) fn test_set(&self) -> (String, String, Option<u64>) {
        (
            self.data.clone().unwrap_or_default(),
            self.cap_m.map_or(String::new(), |c| format!("{c}")),
            self.images,
        )
    }
}

pub(crate) fn file_name(p: &Path) -> Option<&str> {
    p.file_name().and_then(|n| n.to_str())
}

pub(crate) fn read_json(p: &Path) -> Result<Value, String> {
    let text = std::fs::read_to_string(p).map_err(|e| format!("cannot read: {e}"))?;
    serde_json::from_str(&text).map_err(|e| format!("not valid JSON: {e}"))
}

pub(crate) fn string_at(v: &Value, path: &[&str]) -> Option<String> {
    let mut cur = v;
    for k in path {
        cur = cur.get(k)?;
    }
    cur.as_str().map(str::to_string)
}
