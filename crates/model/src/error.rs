//! Errors of the model crate.

use std::path::PathBuf;

/// One tensor whose shape differs between a file and the network.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ShapeMismatch {
    /// Variable name in the network (`rgb.layer1.0.conv1.weight`).
    pub name: String,
    /// Shape expected by the network.
    pub expected: Vec<i64>,
    /// Shape found in the file.
    pub found: Vec<i64>,
}

fn list_mismatches(m: &[ShapeMismatch]) -> String {
    m.iter()
        .map(|s| {
            format!(
                "\n  {}: network {:?}, file {:?}",
                s.name, s.expected, s.found
            )
        })
        .collect()
}

fn list_names(names: &[String]) -> String {
    names.iter().map(|n| format!("\n  {n}")).collect()
}

/// Everything that can go wrong building, running, saving or loading a network.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// An unknown preset or `--set` key, or a config no network can be built with.
    #[error(transparent)]
    Config(#[from] depthsense_config::ConfigError),
    /// A PDA preset or config file that is unknown, unreadable or invalid.
    #[error(transparent)]
    PdaConfig(#[from] depthsense_config::pda::PdaConfigError),
    /// A network's or PDA's config that cannot be written as JSON into its checkpoint's
    /// header.
    #[error("invalid model config: {source}")]
    ConfigJson {
        #[source]
        source: serde_json::Error,
    },
    /// A tensor (`name`, a variable of the network) whose element type (`kind`) no weight
    /// file stores.
    #[error("tensor {name}: dtype {kind:?} cannot be saved")]
    UnsavableDtype { name: String, kind: tch::Kind },
    /// `parse_device` got a string it does not understand.
    #[error(transparent)]
    InvalidDevice(#[from] depthsense_config::device::InvalidDevice),
    /// CUDA was asked for explicitly but libtorch sees no usable GPU.
    #[error("device `{0}` requested but CUDA is not available (libtorch sees {1} GPUs; is libtorch_cuda linked and a driver present?): use --device cpu, or auto (CUDA when there is one)")]
    CudaUnavailable(String, i64),
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// A file is truncated, foreign or otherwise not what was expected.
    #[error("{path}: {msg}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        msg: String,
    },
    /// Tensors in a file have other shapes than the network's variables.
    #[error("{path}: {} tensor(s) with mismatching shapes:{}", .mismatches.len(), list_mismatches(.mismatches))]
    ShapeMismatch {
        /// The file.
        path: PathBuf,
        /// Every offending tensor.
        mismatches: Vec<ShapeMismatch>,
    },
    /// Variables of the network are absent from a checkpoint that must cover it fully.
    #[error("{path}: {} network variable(s) missing from the file:{}", .names.len(), list_names(.names))]
    MissingTensors {
        /// The file.
        path: PathBuf,
        /// The missing variable names.
        names: Vec<String>,
    },
    /// A weight file (safetensors, `torch.save`) that cannot be read or written.
    #[error(transparent)]
    Weights(#[from] depthsense_weights::WeightsError),
    /// An error from libtorch.
    #[error("libtorch: {0}")]
    Torch(#[from] tch::TchError),
}

impl ModelError {
    pub fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        ModelError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
    pub fn format(path: &std::path::Path, msg: impl Into<String>) -> Self {
        ModelError::Format {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The checkpoint writer's refusals: a tensor's type, a config's JSON.
    #[test]
    fn unsavable_config_and_dtype_messages() {
        let e = ModelError::UnsavableDtype {
            name: "rgb.conv1.weight".into(),
            kind: tch::Kind::ComplexFloat,
        };
        assert_eq!(
            e.to_string(),
            "tensor rgb.conv1.weight: dtype ComplexFloat cannot be saved"
        );
        let json = || serde_json::from_str::<u8>("x").unwrap_err();
        let e = ModelError::ConfigJson { source: json() };
        assert_eq!(e.to_string(), format!("invalid model config: {}", json()));
        assert_eq!(
            e.to_string(),
            "invalid model config: expected value at line 1 column 1"
        );
        assert!(std::error::Error::source(&e).is_some());
    }
}
