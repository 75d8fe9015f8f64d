//! The error of the torch-free data layer: each names the file, record or setting at fault.
//! `depthsense_data::TrainError` takes every variant over unchanged (`From`).

use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: cannot parse: {reason}")]
    Parse { path: String, reason: String },
    #[error("data: {0}")]
    Data(String),
    #[error("configuration: {0}")]
    Config(String),
    #[error(transparent)]
    Metrics(#[from] depthsense_metrics::MetricsError),
    #[error("{dir} already holds {what}; nothing was changed: {advice}")]
    OutputExists {
        dir: String,
        what: String,
        advice: String,
    },
    /// `--data` is not a prepared folder (no `index.json`); what it is instead says what to do.
    #[error("{}", no_index_text(.root, .found))]
    NoIndex { root: String, found: NotPrepared },
    #[error("{0}")]
    Other(String),
}

/// What a folder without `index.json` holds.
#[derive(Debug, Clone, PartialEq)]
pub enum NotPrepared {
    /// No such folder; prepared folders beside where it would be.
    Missing { prepared_siblings: Vec<String> },
    /// Shard indexes of a sharded `prepare` not merged yet.
    Shards(Vec<String>),
    /// A nuScenes dataroot (its version folders).
    Dataroot(Vec<String>),
    /// Anything else.
    Other,
}

fn no_index_text(root: &str, found: &NotPrepared) -> String {
    let run_prepare =
        "run `depthsense prepare --dataroot DATAROOT --version VERSION --out FOLDER` \
                       and pass that FOLDER";
    match found {
        NotPrepared::Missing { prepared_siblings } if !prepared_siblings.is_empty() => format!(
            "{root}: no such folder; prepared folders beside it: {} (or {run_prepare})",
            prepared_siblings.join(", ")
        ),
        NotPrepared::Missing { .. } => {
            format!("{root}: no such folder; --data takes a folder written by `depthsense prepare`: {run_prepare}")
        }
        NotPrepared::Shards(shards) => format!(
            "{root} holds the shard indexes of a sharded prepare ({}) but no index.json: merge \
             them first with `depthsense index merge {root}`",
            shards.join(", ")
        ),
        NotPrepared::Dataroot(versions) => format!(
            "{root} is a nuScenes dataroot ({}), not a prepared folder: run `depthsense prepare \
             --dataroot {root} --version {} --out FOLDER` and pass that FOLDER",
            versions.join(", "),
            versions.first().map_or("VERSION", String::as_str)
        ),
        NotPrepared::Other => {
            format!("{root}: no index.json, so not a prepared folder: {run_prepare}")
        }
    }
}

impl DataError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.display().to_string(),
            source,
        }
    }
}
