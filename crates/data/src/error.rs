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
