//! Owned serde rows of the 13 nuScenes tables, written exactly as the devkit reads them.

use serde::Serialize;

#[derive(Debug, Clone, Serialize)]
pub struct Category {
    pub token: String,
    pub name: String,
    pub description: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Attribute {
    pub token: String,
    pub name: String,
    pub description: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Visibility {
    pub token: String,
    pub level: String,
    pub description: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Instance {
    pub token: String,
    pub category_token: String,
    pub nbr_annotations: usize,
    pub first_annotation_token: String,
    pub last_annotation_token: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Sensor {
    pub token: String,
    pub channel: String,
    pub modality: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct CalibratedSensor {
    pub token: String,
    pub sensor_token: String,
    pub translation: [f64; 3],
    pub rotation: [f64; 4],
    pub camera_intrinsic: Vec<[f64; 3]>,
}

#[derive(Debug, Clone, Serialize)]
pub struct EgoPose {
    pub token: String,
    pub timestamp: i64,
    pub rotation: [f64; 4],
    pub translation: [f64; 3],
}

#[derive(Debug, Clone, Serialize)]
pub struct Log {
    pub token: String,
    pub logfile: String,
    pub vehicle: String,
    pub date_captured: String,
    pub location: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Scene {
    pub token: String,
    pub log_token: String,
    pub nbr_samples: usize,
    pub first_sample_token: String,
    pub last_sample_token: String,
    pub name: String,
    pub description: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Sample {
    pub token: String,
    pub timestamp: i64,
    pub prev: String,
    pub next: String,
    pub scene_token: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct SampleData {
    pub token: String,
    pub sample_token: String,
    pub ego_pose_token: String,
    pub calibrated_sensor_token: String,
    pub timestamp: i64,
    pub fileformat: String,
    pub is_key_frame: bool,
    pub height: u32,
    pub width: u32,
    pub filename: String,
    pub prev: String,
    pub next: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct SampleAnnotation {
    pub token: String,
    pub sample_token: String,
    pub instance_token: String,
    pub visibility_token: String,
    pub attribute_tokens: Vec<String>,
    pub translation: [f64; 3],
    /// width, length, height (nuScenes order).
    pub size: [f64; 3],
    pub rotation: [f64; 4],
    pub prev: String,
    pub next: String,
    pub num_lidar_pts: u32,
    pub num_radar_pts: u32,
    /// Box velocity (global frame, m/s). Not a nuScenes column (the devkit derives velocity
    /// from neighbouring annotations); extra keys are ignored by readers.
    pub velocity: [f64; 3],
}

#[derive(Debug, Clone, Serialize)]
pub struct MapRow {
    pub token: String,
    pub log_tokens: Vec<String>,
    pub category: String,
    pub filename: String,
}

/// All tables of a version folder.
#[derive(Debug, Default)]
pub struct Tables {
    pub category: Vec<Category>,
    pub attribute: Vec<Attribute>,
    pub visibility: Vec<Visibility>,
    pub instance: Vec<Instance>,
    pub sensor: Vec<Sensor>,
    pub calibrated_sensor: Vec<CalibratedSensor>,
    pub ego_pose: Vec<EgoPose>,
    pub log: Vec<Log>,
    pub scene: Vec<Scene>,
    pub sample: Vec<Sample>,
    pub sample_data: Vec<SampleData>,
    pub sample_annotation: Vec<SampleAnnotation>,
    pub map: Vec<MapRow>,
}

impl Tables {
    /// (file stem, pretty JSON bytes) of every table.
    pub fn to_json(&self) -> serde_json::Result<Vec<(&'static str, Vec<u8>)>> {
        Ok(vec![
            ("category", serde_json::to_vec_pretty(&self.category)?),
            ("attribute", serde_json::to_vec_pretty(&self.attribute)?),
            ("visibility", serde_json::to_vec_pretty(&self.visibility)?),
            ("instance", serde_json::to_vec_pretty(&self.instance)?),
            ("sensor", serde_json::to_vec_pretty(&self.sensor)?),
            (
                "calibrated_sensor",
                serde_json::to_vec_pretty(&self.calibrated_sensor)?,
            ),
            ("ego_pose", serde_json::to_vec_pretty(&self.ego_pose)?),
            ("log", serde_json::to_vec_pretty(&self.log)?),
            ("scene", serde_json::to_vec_pretty(&self.scene)?),
            ("sample", serde_json::to_vec_pretty(&self.sample)?),
            ("sample_data", serde_json::to_vec_pretty(&self.sample_data)?),
            (
                "sample_annotation",
                serde_json::to_vec_pretty(&self.sample_annotation)?,
            ),
            ("map", serde_json::to_vec_pretty(&self.map)?),
        ])
    }
}
