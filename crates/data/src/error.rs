//! Errors of the train crate: each names the file, record or setting at fault.

use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
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
    Model(#[from] depthsense_model::ModelError),
    #[error(transparent)]
    Metrics(#[from] depthsense_metrics::MetricsError),
    #[error(transparent)]
    Viz(#[from] depthsense_viz::VizError),
    #[error("libtorch: {0}")]
    Torch(#[from] tch::TchError),
    #[error(
        "non-finite loss ({loss}) at epoch {epoch}, iteration {iteration}: training stopped; \
         the last good checkpoint is kept at {kept}"
    )]
    NonFiniteLoss {
        loss: f64,
        epoch: u64,
        iteration: u64,
        kept: String,
    },
    #[error("{dir} already holds {what}; nothing was changed: {advice}")]
    OutputExists {
        dir: String,
        what: String,
        advice: String,
    },
    #[error(transparent)]
    Lock(#[from] depthsense_nuscenes::lock::LockError),
    #[error("{0}")]
    Other(String),
}

impl TrainError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.display().to_string(),
            source,
        }
    }
}

impl From<depthsense_dist::DistError> for TrainError {
    fn from(e: depthsense_dist::DistError) -> Self {
        TrainError::Other(e.to_string())
    }
}

/// An unknown preset or `--set` key, or a config no network can be built with.
impl From<depthsense_model::config::ConfigError> for TrainError {
    fn from(e: depthsense_model::config::ConfigError) -> Self {
        TrainError::Model(e.into())
    }
}

/// The torch-free layer's errors become the same variants here (same messages).
impl From<depthsense_dataset::DataError> for TrainError {
    fn from(e: depthsense_dataset::DataError) -> Self {
        use depthsense_dataset::DataError as D;
        match e {
            D::Io { path, source } => TrainError::Io { path, source },
            D::Parse { path, reason } => TrainError::Parse { path, reason },
            D::Data(m) => TrainError::Data(m),
            D::Config(m) => TrainError::Config(m),
            D::Metrics(m) => TrainError::Metrics(m),
            D::OutputExists { dir, what, advice } => TrainError::OutputExists { dir, what, advice },
            D::Other(m) => TrainError::Other(m),
        }
    }
}
