//! Errors of `prepare`, `index` and `inspect`: each names the file, split or setting at fault.

use std::path::Path;

use depthsense_nuscenes::NuError;

/// An error of the prepare pipeline.
#[derive(Debug, thiserror::Error)]
pub enum PrepError {
    #[error(transparent)]
    Nu(#[from] depthsense_nuscenes::NuError),
    #[error("unknown split {0:?}; expected one of train, val, test, test-day, test-night, test-rain, official-train, official-val, all")]
    UnknownSplit(String),
    #[error("split {split:?} matches no scene of {version} ({scenes} scenes); synthetic or partial datasets have their own scene tokens: use --split all")]
    EmptySplit {
        split: String,
        version: String,
        scenes: usize,
    },
    #[error("{path}: {reason}")]
    Output { path: String, reason: String },
    #[error(transparent)]
    Lock(#[from] depthsense_base::lock::LockError),
    #[error("{path} was prepared with different settings ({what}: {old} there, {new} now); use another --out or remove it")]
    SettingsMismatch {
        path: String,
        what: String,
        old: String,
        new: String,
    },
    #[error(
        "{path}: unreadable prepared index ({reason}); it is not replaced: repair or remove it"
    )]
    CorruptIndex { path: String, reason: String },
    #[error("{path} holds dataset version {old:?}, this run is {new:?}; use another --out")]
    VersionMismatch {
        path: String,
        old: String,
        new: String,
    },
    #[error("sample {sample} panicked while reading {input}: {reason}")]
    Panicked {
        sample: String,
        input: String,
        reason: String,
    },
    #[error("{0}")]
    Shard(String),
    #[error("{0}")]
    Other(String),
}

impl PrepError {
    /// A failed read or write of `path` (the reader's error, naming the file).
    pub(crate) fn io(path: &Path, e: std::io::Error) -> Self {
        PrepError::Nu(NuError::io(path, e))
    }

    /// A failed write of the output folder's shared files (index, locks).
    pub(crate) fn output(path: &Path, e: std::io::Error) -> Self {
        PrepError::Output {
            path: path.display().to_string(),
            reason: e.to_string(),
        }
    }
}
