//! Errors of the nuScenes data layer: each names the file or record and the problem.

use std::path::Path;

/// Result alias of this crate.
pub type Result<T, E = NuError> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum NuError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Pcd { path: String, reason: String },
    #[error("{path}: invalid table JSON: {reason}")]
    Json { path: String, reason: String },
    #[error("{table} row {token}: field {field} points at missing {target} token {missing}")]
    MissingToken {
        table: &'static str,
        token: String,
        field: &'static str,
        target: &'static str,
        missing: String,
    },
    #[error("{table} row {token}: {reason}")]
    BadRecord {
        table: &'static str,
        token: String,
        reason: String,
    },
    #[error("{record}: quaternion (w,x,y,z) = {q:?} is not unit (norm {norm:.6})")]
    NonUnitQuaternion {
        record: String,
        q: [f64; 4],
        norm: f64,
    },
    #[error("{path}: cannot decode image: {reason}")]
    Image { path: String, reason: String },
    #[error("{0}")]
    Other(String),
}

impl NuError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        NuError::Io {
            path: path.display().to_string(),
            source,
        }
    }
}
