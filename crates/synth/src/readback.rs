//! A small, independent reader of a generated dataroot (tables as JSON values, poses and the
//! SPEC §2 projection chain). Used by the contact sheet and the self-checks of this crate;
//! depthsense's own reader lives in `depthsense_nuscenes`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use serde_json::Value;

use crate::calib::{CAM_CX, CAM_CY, CAM_FX, CAM_FY, IMG_H, IMG_W};
use crate::SynthError;

/// Tables of a version folder, indexed by token.
pub struct Dataroot {
    pub root: PathBuf,
    pub scenes: Vec<Value>,
    pub samples: HashMap<String, Value>,
    pub sample_data: HashMap<String, Value>,
    pub ego_pose: HashMap<String, Value>,
    pub calibrated_sensor: HashMap<String, Value>,
    pub sensor_channel: HashMap<String, String>,
    /// (sample token, channel) → keyframe sample_data token.
    pub keyframe: HashMap<(String, String), String>,
}

fn read_rows(dir: &Path, name: &str) -> Result<Vec<Value>, SynthError> {
    let p = dir.join(format!("{name}.json"));
    let b = std::fs::read(&p).map_err(|source| SynthError::Io {
        path: p.display().to_string(),
        source,
    })?;
    match serde_json::from_slice::<Value>(&b) {
        Ok(Value::Array(v)) => Ok(v),
        Ok(_) => Err(SynthError::Data(format!(
            "{}: not a JSON list",
            p.display()
        ))),
        Err(e) => Err(SynthError::Data(format!("{}: {e}", p.display()))),
    }
}

fn by_token(rows: Vec<Value>) -> HashMap<String, Value> {
    rows.into_iter()
        .filter_map(|r| Some((r.get("token")?.as_str()?.to_string(), r)))
        .collect()
}

fn f64s<const N: usize>(v: &Value, key: &str, what: &str) -> Result<[f64; N], SynthError> {
    let arr = v
        .get(key)
        .and_then(|a| a.as_array())
        .ok_or_else(|| SynthError::Data(format!("{what}: no {key}")))?;
    if arr.len() != N {
        return Err(SynthError::Data(format!(
            "{what}: {key} has {} values",
            arr.len()
        )));
    }
    let mut out = [0.0; N];
    for (o, x) in out.iter_mut().zip(arr) {
        *o = x
            .as_f64()
            .ok_or_else(|| SynthError::Data(format!("{what}: {key} not numeric")))?;
    }
    Ok(out)
}

fn quat(wxyz: [f64; 4]) -> DQuat {
    DQuat::from_xyzw(wxyz[1], wxyz[2], wxyz[3], wxyz[0]).normalize()
}

/// A rigid transform p ↦ R p + t.
#[derive(Debug, Clone, Copy)]
pub struct Rigid {
    pub r: DMat3,
    pub t: DVec3,
}

impl Rigid {
    pub fn apply(&self, p: DVec3) -> DVec3 {
        self.r * p + self.t
    }
    pub fn inverse(&self) -> Rigid {
        let rt = self.r.transpose();
        Rigid {
            r: rt,
            t: -(rt * self.t),
        }
    }
    pub fn then(&self, next: &Rigid) -> Rigid {
        Rigid {
            r: next.r * self.r,
            t: next.r * self.t + next.t,
        }
    }
}

impl Dataroot {
    pub fn load(root: &Path, version: &str) -> Result<Dataroot, SynthError> {
        let dir = root.join(version);
        let sensors = by_token(read_rows(&dir, "sensor")?);
        let sensor_channel = sensors
            .iter()
            .filter_map(|(k, v)| Some((k.clone(), v.get("channel")?.as_str()?.to_string())))
            .collect();
        let calibrated_sensor = by_token(read_rows(&dir, "calibrated_sensor")?);
        let sample_data = by_token(read_rows(&dir, "sample_data")?);
        let mut d = Dataroot {
            root: root.to_path_buf(),
            scenes: read_rows(&dir, "scene")?,
            samples: by_token(read_rows(&dir, "sample")?),
            sample_data,
            ego_pose: by_token(read_rows(&dir, "ego_pose")?),
            calibrated_sensor,
            sensor_channel,
            keyframe: HashMap::new(),
        };
        let mut kf = HashMap::new();
        for (tok, sd) in &d.sample_data {
            if sd.get("is_key_frame").and_then(|v| v.as_bool()) == Some(true) {
                let ch = d.channel(tok)?;
                let st = sd
                    .get("sample_token")
                    .and_then(|v| v.as_str())
                    .unwrap_or_default()
                    .to_string();
                kf.insert((st, ch), tok.clone());
            }
        }
        d.keyframe = kf;
        Ok(d)
    }

    fn sd(&self, tok: &str) -> Result<&Value, SynthError> {
        self.sample_data
            .get(tok)
            .ok_or_else(|| SynthError::Data(format!("sample_data {tok} not found")))
    }

    fn field<'a>(v: &'a Value, key: &str, what: &str) -> Result<&'a str, SynthError> {
        v.get(key)
            .and_then(|x| x.as_str())
            .ok_or_else(|| SynthError::Data(format!("{what}: no {key}")))
    }

    pub fn channel(&self, sd_tok: &str) -> Result<String, SynthError> {
        let sd = self.sd(sd_tok)?;
        let cs_tok = Self::field(sd, "calibrated_sensor_token", sd_tok)?;
        let cs = self
            .calibrated_sensor
            .get(cs_tok)
            .ok_or_else(|| SynthError::Data(format!("calibrated_sensor {cs_tok} not found")))?;
        let s_tok = Self::field(cs, "sensor_token", cs_tok)?;
        self.sensor_channel
            .get(s_tok)
            .cloned()
            .ok_or_else(|| SynthError::Data(format!("sensor {s_tok} not found")))
    }

    pub fn path(&self, sd_tok: &str) -> Result<PathBuf, SynthError> {
        Ok(self
            .root
            .join(Self::field(self.sd(sd_tok)?, "filename", sd_tok)?))
    }

    /// ego_from_sensor of a sample_data.
    pub fn ego_from_sensor(&self, sd_tok: &str) -> Result<Rigid, SynthError> {
        let sd = self.sd(sd_tok)?;
        let cs_tok = Self::field(sd, "calibrated_sensor_token", sd_tok)?;
        let cs = self
            .calibrated_sensor
            .get(cs_tok)
            .ok_or_else(|| SynthError::Data(format!("calibrated_sensor {cs_tok} not found")))?;
        Ok(Rigid {
            r: DMat3::from_quat(quat(f64s::<4>(cs, "rotation", cs_tok)?)),
            t: DVec3::from_array(f64s::<3>(cs, "translation", cs_tok)?),
        })
    }

    /// global_from_ego at the sample_data's timestamp.
    pub fn global_from_ego(&self, sd_tok: &str) -> Result<Rigid, SynthError> {
        let sd = self.sd(sd_tok)?;
        let e_tok = Self::field(sd, "ego_pose_token", sd_tok)?;
        let e = self
            .ego_pose
            .get(e_tok)
            .ok_or_else(|| SynthError::Data(format!("ego_pose {e_tok} not found")))?;
        Ok(Rigid {
            r: DMat3::from_quat(quat(f64s::<4>(e, "rotation", e_tok)?)),
            t: DVec3::from_array(f64s::<3>(e, "translation", e_tok)?),
        })
    }

    /// camera_from_sensor through both ego poses (SPEC §2).
    pub fn cam_from_sensor(&self, sd_pts: &str, sd_cam: &str) -> Result<Rigid, SynthError> {
        let a = self.ego_from_sensor(sd_pts)?;
        let b = self.global_from_ego(sd_pts)?;
        let c = self.global_from_ego(sd_cam)?.inverse();
        let d = self.ego_from_sensor(sd_cam)?.inverse();
        Ok(a.then(&b).then(&c).then(&d))
    }
}

/// Project camera-frame points: (u, v, depth) for depth > 1 m and 1 < u < W−1, 1 < v < H−1
/// (SPEC §2).
pub fn project(cam_pts: impl Iterator<Item = DVec3>) -> Vec<(f64, f64, f64)> {
    cam_pts
        .filter_map(|p| {
            if p.z <= 1.0 {
                return None;
            }
            let u = CAM_FX * p.x / p.z + CAM_CX;
            let v = CAM_FY * p.y / p.z + CAM_CY;
            (u > 1.0 && u < IMG_W as f64 - 1.0 && v > 1.0 && v < IMG_H as f64 - 1.0)
                .then_some((u, v, p.z))
        })
        .collect()
}
