//! `FILE.json` beside an exported model (`depthsense export`): the fields the report shows,
//! typed; the rest (`model_config`, `sid`, `frame`, `radar_maps`, the tensors' `dtype` and
//! `meaning`, …) as written. `export::Sidecar` is the whole of it, written through this record.
//!
//! Version: `"format_version": "depthsense-export-v1"` (a string since the first sidecar; a
//! deployment reads it).

use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::{Rest, Versioned};

/// The sidecar's `format_version`.
pub const SIDECAR_FORMAT: &str = "depthsense-export-v1";

/// The version number of a sidecar format word (`depthsense-export-v1` → 1); `None`: not a
/// sidecar of depthsense.
pub fn sidecar_version(format_version: &str) -> Option<u32> {
    format_version
        .strip_prefix("depthsense-export-v")?
        .parse()
        .ok()
}

/// The sidecar JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SidecarRecord {
    pub format_version: String,
    /// onnx | torchscript | pytorch
    pub format: String,
    /// fp32 | fp16
    pub precision: String,
    /// "dynamic" or N.
    pub batch: String,
    /// The preset the config was built from.
    pub preset: String,
    pub checkpoint: String,
    pub checkpoint_sha256: String,
    pub inputs: Vec<TensorShape>,
    pub output: TensorShape,
    /// The radar the network was trained on (absent when the checkpoint does not record it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trained_radar: Option<TrainedRadar>,
    #[serde(flatten)]
    pub rest: Rest,
}

impl Versioned for SidecarRecord {
    const CURRENT: u32 = 1;
    fn format_version(&self) -> u32 {
        sidecar_version(&self.format_version).unwrap_or(u32::MAX)
    }
}

/// An input or output of the graph: its name and sizes (`"N"`: the dynamic batch axis).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TensorShape {
    pub name: String,
    pub shape: Vec<Value>,
    /// `dtype`, `meaning`.
    #[serde(flatten)]
    pub rest: Rest,
}

impl TensorShape {
    /// `` `image` [N, 3, 350, 800] ``.
    pub fn words(&self) -> String {
        let dims: Vec<String> = self
            .shape
            .iter()
            .map(|d| d.as_str().map_or(d.to_string(), str::to_string))
            .collect();
        format!("`{}` [{}]", self.name, dims.join(", "))
    }
}

/// `prep::calibration::RadarSettings` as the sidecar records it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainedRadar {
    pub radar_sweeps: u64,
    pub radar_channels: Vec<String>,
    pub radar_filters: bool,
    pub radar_velocity_compensation: bool,
    #[serde(flatten)]
    pub rest: Rest,
}
