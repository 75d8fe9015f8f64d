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
    #[error("{0}")]
    Other(String),
}

impl DataError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.display().to_string(),
            source,
        }
    }
}
