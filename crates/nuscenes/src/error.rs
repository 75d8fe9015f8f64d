//! Errors of the nuScenes data layer: each names the file or record and the problem.

use std::path::{Path, PathBuf};

/// Result alias of this crate.
pub type Result<T, E = NuError> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum NuError {
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
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
    /// `--version` names no folder of the dataroot; `found` lists the version folders there
    /// (folders holding `scene.json`).
    #[error("{}", version_not_found(.dataroot, .version, .found))]
    VersionNotFound {
        dataroot: String,
        version: String,
        found: Vec<String>,
    },
}

fn version_not_found(dataroot: &str, version: &str, found: &[String]) -> String {
    let head = format!("{dataroot}: no version folder `{version}`");
    match found {
        [] if !Path::new(dataroot).is_dir() => {
            format!("{dataroot}: no such dataroot folder (the folder that holds samples/, sweeps/ and the version folder)")
        }
        [] => format!(
            "{head}, and no version folder at all (a folder holding scene.json, sample.json, …): \
             is this the nuScenes dataroot (the folder that holds samples/, sweeps/ and \
             v1.0-*/)? A synthetic world is made by `depthsense synth --out {dataroot}`"
        ),
        [one] => format!("{head}; it holds `{one}`: pass --version {one}"),
        many => format!(
            "{head}; it holds {}: pass one of them with --version",
            many.iter()
                .map(|v| format!("`{v}`"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

impl NuError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        NuError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}
