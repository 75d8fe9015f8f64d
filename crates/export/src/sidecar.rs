//! `FILE.json` beside an exported model: everything a deployment needs to feed it correctly —
//! the model config, the tensors' names, shapes and units, the radar channels in order, the SID
//! parameters, the frame convention (SPEC §3), how each radar map is built (SPEC §5), the
//! depthsense version and the checkpoint's SHA-256.

use std::io::Read;
use std::path::Path;

use depthsense_config::{Fusion, ModelConfig, RadarInput, SidConfig};
use depthsense_prep::calibration::RadarSettings;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::{Batch, ExportError, ExportOptions};

/// The sidecar's `format_version`.
pub use depthsense_records::sidecar::SIDECAR_FORMAT;

/// One input or output of the graph.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TensorSpec {
    pub name: String,
    pub dtype: String,
    /// Sizes; the batch axis is `"N"` when dynamic.
    pub shape: Vec<serde_json::Value>,
    /// What the values are.
    pub meaning: String,
}

/// The training frame (SPEC §3).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    pub width: i64,
    pub height: i64,
    /// CAM_FRONT 1600x900 scaled by this factor...
    pub scale: f64,
    /// ...then this many rows cropped at the top.
    pub crop_top_rows: i64,
    pub convention: String,
}

/// How the radar maps are built (SPEC §5), with the parameters depthsense uses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RadarMaps {
    pub raw: String,
    pub height_extended: String,
    pub height_up_m: f64,
    pub height_down_m: f64,
    pub mer: String,
    pub mer_thresholds: Vec<f64>,
    pub empty_pixels: String,
}

/// The sidecar JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sidecar {
    pub format_version: String,
    /// onnx | torchscript | pytorch
    pub format: String,
    pub depthsense_version: String,
    pub checkpoint: String,
    pub checkpoint_sha256: String,
    /// The preset the config was built from (`model_config.name`).
    pub preset: String,
    pub model_config: ModelConfig,
    /// "dynamic" or N.
    pub batch: String,
    /// fp32 | fp16 (arithmetic inside; inputs and output are float32).
    pub precision: String,
    pub inputs: Vec<TensorSpec>,
    pub output: TensorSpec,
    /// The radar input kind (None for an RGB-only network) and its channels in order.
    pub radar_input: Option<RadarInput>,
    pub radar_channels: Vec<String>,
    pub sid: SidConfig,
    pub frame: Frame,
    pub radar_maps: RadarMaps,
    /// The radar the network was trained on — sweeps per channel, channels, the devkit
    /// filters, velocity compensation — as `prepare` recorded it for the training data (absent
    /// when the checkpoint does not record it: a `.pth`, or one trained before this field).
    /// Feed the deployed model radar gathered the same way.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trained_radar: Option<RadarSettings>,
}

/// The radar channels of `input`, in the order the graph takes them.
pub fn radar_channel_names(input: RadarInput) -> Vec<String> {
    let thresholds = depthsense_dataset::mer_maps::THRESHOLDS;
    match input {
        RadarInput::Height => vec!["height-extended depth (m)".into()],
        RadarInput::Raw => vec!["raw depth (m)".into()],
        RadarInput::RawHeight => vec!["raw depth (m)".into(), "height-extended depth (m)".into()],
        RadarInput::Mer => std::iter::once("raw depth (m)".to_string())
            .chain(
                thresholds
                    .iter()
                    .map(|t| format!("MER depth where confidence > {t} (m)")),
            )
            .collect(),
    }
}

/// SHA-256 of a file, lowercase hex.
pub fn sha256_file(path: &Path) -> Result<String, ExportError> {
    let mut f = std::fs::File::open(path).map_err(|e| ExportError::io(path, e))?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f.read(&mut buf).map_err(|e| ExportError::io(path, e))?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

impl Sidecar {
    /// The sidecar as the record the report reads (`depthsense_records::sidecar`): the same
    /// JSON, checked to carry every field it shows; `path`: where it is written.
    pub fn record(
        &self,
        path: &Path,
    ) -> Result<depthsense_records::sidecar::SidecarRecord, depthsense_records::RecordError> {
        depthsense_records::convert(self, path)
    }

    /// The text of `path` (pretty JSON, keys sorted, a final newline), written through
    /// [`Sidecar::record`].
    pub fn to_json(&self, path: &Path) -> Result<String, depthsense_records::RecordError> {
        let record = self.record(path)?;
        let text = depthsense_records::to_json_pretty(&record)
            .map_err(|e| depthsense_records::RecordError::new(path, e.to_string()))?;
        Ok(format!("{text}\n"))
    }

    /// The sidecar of exporting `opts.checkpoint` as the network `cfg`.
    pub fn new(
        opts: &ExportOptions,
        cfg: &ModelConfig,
        trained_radar: Option<RadarSettings>,
    ) -> Result<Self, ExportError> {
        let n = match opts.batch {
            Batch::Dynamic => serde_json::json!("N"),
            Batch::Fixed(n) => serde_json::json!(n),
        };
        let (h, w) = (cfg.out_height, cfg.out_width);
        let radar_input = (cfg.fusion != Fusion::None).then_some(cfg.radar_input);
        let mut inputs = vec![TensorSpec {
            name: "image".into(),
            dtype: "float32".into(),
            shape: vec![n.clone(), 3.into(), h.into(), w.into()],
            meaning: "RGB in [0, 1], the training frame (SPEC §3); the ImageNet normalisation \
                      and any input downscaling happen inside the graph"
                .into(),
        }];
        if let Some(r) = radar_input {
            inputs.push(TensorSpec {
                name: "radar".into(),
                dtype: "float32".into(),
                shape: vec![n.clone(), cfg.radar_channels.into(), h.into(), w.into()],
                meaning: format!(
                    "radar maps in metres, 0 = no return: the '{}' input, channels as in \
                     radar_channels (SPEC §5, radar_maps)",
                    r.name()
                ),
            });
        }
        Ok(Self {
            format_version: SIDECAR_FORMAT.into(),
            format: opts.format.name().into(),
            depthsense_version: env!("CARGO_PKG_VERSION").into(),
            checkpoint: opts.checkpoint.display().to_string(),
            checkpoint_sha256: sha256_file(&opts.checkpoint)?,
            preset: cfg.name.clone(),
            model_config: cfg.clone(),
            batch: opts.batch.arg(),
            precision: opts.precision.name().into(),
            inputs,
            output: TensorSpec {
                name: "depth".into(),
                dtype: "float32".into(),
                shape: vec![n, 1.into(), h.into(), w.into()],
                meaning: "depth in metres, decoded as `depthsense predict` decodes it (SID bin \
                          centres for the ordinal head, SPEC §7)"
                    .into(),
            },
            radar_channels: radar_input.map(radar_channel_names).unwrap_or_default(),
            radar_input,
            sid: cfg.sid,
            frame: frame(),
            radar_maps: radar_maps(),
            trained_radar,
        })
    }
}

/// SPEC §3.
fn frame() -> Frame {
    Frame {
        width: 800,
        height: 350,
        scale: 0.5,
        crop_top_rows: 100,
        convention: "CAM_FRONT 1600x900 scaled by 0.5 to 800x450, the top 100 rows cropped: \
                     800x350. Intrinsics: fx, fy, cx, cy x 0.5, then cy -= 100; a point \
                     projected at full-resolution (u, v) lands at pixel (floor(u/2), \
                     floor(v/2) - 100)."
            .into(),
    }
}

/// SPEC §5 with depthsense's parameters.
fn radar_maps() -> RadarMaps {
    RadarMaps {
        raw: "each radar point projected into CAM_FRONT sets one pixel to its depth; the \
              nearest wins"
            .into(),
        height_extended: "each radar point at full-resolution (u, v) with depth d becomes a \
                          one-pixel-wide vertical strip from v - height_up_m*fy/d to v + \
                          height_down_m*fy/d filled with d, the nearer depth winning where \
                          strips overlap; then reduced to the training frame"
            .into(),
        height_up_m: depthsense_prep::maps::RADAR_H_UP_M as f64,
        height_down_m: depthsense_prep::maps::RADAR_H_DOWN_M as f64,
        mer: "`depthsense mer apply`'s enhanced map: per pixel the most confident associated \
              radar depth and its confidence; channel k is that depth where the confidence \
              exceeds mer_thresholds[k], else 0"
            .into(),
        mer_thresholds: depthsense_dataset::mer_maps::THRESHOLDS
            .iter()
            .map(|&t| t as f64)
            .collect(),
        empty_pixels: "0".into(),
    }
}
