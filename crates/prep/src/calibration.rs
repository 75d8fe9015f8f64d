//! The calibration JSON of `predict --image` (docs/guide/deploy.md, "Raw files"): the camera's
//! intrinsics and, per radar file, its channel, its sweep index, its time and the 4x4 transform
//! from that sweep's sensor into the keyframe camera (ego motion between the two included) —
//! what `prepare` reads from the nuScenes tables, so that raw files can give a model exactly
//! the radar input it was trained on (every sweep, the same filters and velocity
//! compensation). [`for_sample`] writes one from a sample of a dataroot
//! (`depthsense calibration`); [`read`] also takes the first form, which had one transform per
//! file name and nothing else.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use depthsense_nuscenes::geometry::cam_from_sensor;
use depthsense_nuscenes::tables::{NuScenes, Sample};
use depthsense_nuscenes::NuError;
use serde::{Deserialize, Serialize};

use crate::pipeline::{keyframe_sensors, PrepareOptions};
use crate::PrepError;

/// The format tag of what [`for_sample`] writes.
pub const FORMAT: &str = "depthsense-calibration-v2";

/// A camera and the radar sweeps to draw into it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    pub format: String,
    /// The nuScenes sample it was written from (None for a hand-written one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sample_token: Option<String>,
    /// The CAM_FRONT image of that sample, and its time (µs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_file: Option<String>,
    #[serde(default)]
    pub camera_timestamp_us: Option<i64>,
    /// Full resolution (1600x900), row-major.
    pub camera_intrinsic: [[f64; 3]; 3],
    /// Every radar sweep, keyframe sweeps (index 0) first per channel.
    pub radar: Vec<RadarEntry>,
    /// How `prepare` would treat these sweeps (what a model trained on them was fed).
    pub settings: RadarSettings,
}

/// One radar file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RadarEntry {
    /// Its path (absolute, or relative to the calibration JSON's folder).
    pub file: String,
    /// `RADAR_FRONT`, …
    pub channel: String,
    /// 0 = the keyframe sweep, 1 = the one before, …
    pub sweep: usize,
    #[serde(default)]
    pub timestamp_us: Option<i64>,
    /// Sweep sensor → keyframe camera, 4x4 row-major, metres.
    pub cam_from_radar: [[f64; 4]; 4],
}

/// The radar settings of a prepared folder's `index.json` that decide a model's radar input.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RadarSettings {
    pub radar_sweeps: usize,
    pub radar_channels: Vec<String>,
    pub radar_filters: bool,
    pub radar_velocity_compensation: bool,
}

impl RadarSettings {
    /// The settings of `opts`.
    pub fn of(opts: &PrepareOptions) -> Self {
        RadarSettings {
            radar_sweeps: opts.radar_sweeps.max(1),
            radar_channels: opts.radar_channels.clone(),
            radar_filters: opts.radar_filters,
            radar_velocity_compensation: opts.radar_velocity_compensation,
        }
    }

    /// The settings recorded in a prepared folder's index or a checkpoint (`settings` map of
    /// `pipeline::settings_map`); None when they are not all there (an older folder).
    pub fn from_map(m: &BTreeMap<String, serde_json::Value>) -> Option<Self> {
        Some(RadarSettings {
            radar_sweeps: m.get("radar_sweeps")?.as_u64()? as usize,
            radar_channels: serde_json::from_value(m.get("radar_channels")?.clone()).ok()?,
            radar_filters: m.get("radar_filters")?.as_bool()?,
            radar_velocity_compensation: m.get("radar_velocity_compensation")?.as_bool()?,
        })
    }

    /// How `other` (an input) differs from these (training's), one phrase per difference.
    pub fn differences(&self, input: &RadarSettings) -> Vec<String> {
        let mut d = vec![];
        if input.radar_sweeps < self.radar_sweeps {
            d.push(format!(
                "{} radar sweep(s) per channel where training had {}",
                input.radar_sweeps, self.radar_sweeps
            ));
        }
        let missing: Vec<&String> = self
            .radar_channels
            .iter()
            .filter(|c| !input.radar_channels.contains(c))
            .collect();
        if !missing.is_empty() {
            d.push(format!(
                "no {} (training had {})",
                missing
                    .iter()
                    .map(|c| c.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
                self.radar_channels.join(", ")
            ));
        }
        if input.radar_filters != self.radar_filters {
            d.push(format!(
                "the devkit radar filters {} where training had them {}",
                on_off(input.radar_filters),
                on_off(self.radar_filters)
            ));
        }
        if input.radar_velocity_compensation != self.radar_velocity_compensation {
            d.push(format!(
                "velocity compensation {} where training had it {}",
                on_off(input.radar_velocity_compensation),
                on_off(self.radar_velocity_compensation)
            ));
        }
        d
    }
}

fn on_off(b: bool) -> &'static str {
    if b {
        "on"
    } else {
        "off"
    }
}

/// The calibration of sample `token` of `nu`: its camera and every radar sweep `prepare` with
/// `opts` would read (paths absolute when `nu`'s dataroot is).
pub fn for_sample(
    nu: &NuScenes,
    sample: &Sample,
    opts: &PrepareOptions,
) -> Result<Calibration, PrepError> {
    let ks = keyframe_sensors(nu, sample)?;
    let c = ks.cam;
    let mut radar = vec![];
    for ch in &opts.radar_channels {
        let Some(kf) = nu.keyframe(sample.token, ch) else {
            continue;
        };
        for (i, sw) in nu
            .sweeps_back(kf, opts.radar_sweeps.max(1))
            .into_iter()
            .enumerate()
        {
            radar.push(RadarEntry {
                file: nu.path_of(sw).display().to_string(),
                channel: ch.clone(),
                sweep: i,
                timestamp_us: Some(sw.timestamp_us),
                cam_from_radar: cam_from_sensor(nu, sw, ks.cam_sd)?.to_mat4(),
            });
        }
    }
    Ok(Calibration {
        format: FORMAT.into(),
        sample_token: Some(sample.token.to_string()),
        camera_file: Some(nu.path_of(ks.cam_sd).display().to_string()),
        camera_timestamp_us: Some(ks.cam_sd.timestamp_us),
        camera_intrinsic: [[c.fx, 0.0, c.cx], [0.0, c.fy, c.cy], [0.0, 0.0, 1.0]],
        radar,
        settings: RadarSettings::of(opts),
    })
}

/// The first form: `{"camera_intrinsic": 3x3, "cam_from_radar": {"<file name>": 4x4}}`.
#[derive(Deserialize)]
struct CalibrationV1 {
    camera_intrinsic: [[f64; 3]; 3],
    cam_from_radar: BTreeMap<String, [[f64; 4]; 4]>,
}

/// Reads a calibration JSON of either form. The first form's files are keyframe sweeps
/// (index 0) of the channel their nuScenes name carries (`…__RADAR_FRONT__…`), with the devkit
/// filters and no velocity compensation.
pub fn read(path: &Path) -> Result<Calibration, PrepError> {
    let bytes = std::fs::read(path).map_err(|e| PrepError::io(path, e))?;
    let bad = |reason: String| {
        PrepError::Nu(NuError::Json {
            path: path.display().to_string(),
            reason,
        })
    };
    let v: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| bad(e.to_string()))?;
    if v.get("format").is_some() {
        return serde_json::from_value(v).map_err(|e| {
            bad(format!(
                "{e} (write one with `depthsense calibration --dataroot D --token T --out FILE`)"
            ))
        });
    }
    let v1: CalibrationV1 = serde_json::from_value(v).map_err(|e| {
        bad(format!(
            "{e} (expected the output of `depthsense calibration`, or \
             {{\"camera_intrinsic\": 3x3, \"cam_from_radar\": {{file name: 4x4}}}})"
        ))
    })?;
    let radar: Vec<RadarEntry> = v1
        .cam_from_radar
        .into_iter()
        .map(|(file, m)| RadarEntry {
            channel: channel_of(&file),
            file,
            sweep: 0,
            timestamp_us: None,
            cam_from_radar: m,
        })
        .collect();
    let mut channels: Vec<String> = radar.iter().map(|r| r.channel.clone()).collect();
    channels.sort();
    channels.dedup();
    Ok(Calibration {
        format: "depthsense-calibration-v1".into(),
        sample_token: None,
        camera_file: None,
        camera_timestamp_us: None,
        camera_intrinsic: v1.camera_intrinsic,
        radar,
        settings: RadarSettings {
            radar_sweeps: 1,
            radar_channels: channels,
            radar_filters: true,
            radar_velocity_compensation: false,
        },
    })
}

/// The channel in a nuScenes file name (`<log>__RADAR_FRONT__<time>.pcd`), or `RADAR`.
pub fn channel_of(file_name: &str) -> String {
    file_name
        .split("__")
        .find(|p| p.starts_with("RADAR_"))
        .unwrap_or("RADAR")
        .to_string()
}

/// Where entry `e`'s file is: absolute as written, relative to the calibration's folder.
pub fn file_of(calibration: &Path, e: &RadarEntry) -> PathBuf {
    let p = PathBuf::from(&e.file);
    if p.is_absolute() {
        p
    } else {
        calibration.parent().unwrap_or(Path::new(".")).join(p)
    }
}

/// The camera image a calibration names (`camera_file`; relative to the calibration's folder
/// when relative), if it names one.
pub fn camera_file_of(calibration: &Path, c: &Calibration) -> Option<PathBuf> {
    let p = PathBuf::from(c.camera_file.as_ref()?);
    Some(if p.is_absolute() {
        p
    } else {
        calibration.parent().unwrap_or(Path::new(".")).join(p)
    })
}

/// Writes `c` as pretty JSON, atomically.
pub fn write(path: &Path, c: &Calibration) -> Result<(), PrepError> {
    let bytes = serde_json::to_vec_pretty(c).map_err(|e| PrepError::encode(path.display(), e))?;
    depthsense_base::fsutil::write_atomic(path, &bytes).map_err(|e| PrepError::io(path, e))
}
