//! The on-disk layout of `depthsense prepare` output — the contract between `prep`
//! (writer) and `train` (reader). Changing a name here changes both.
//!
//! ```text
//! O/index.json                 PreparedIndex
//! O/<sample_token>/image.png   800x350 RGB8 (SPEC §3: ×0.5, top 100 rows cropped)
//!                 /lidar_sparse.png    16-bit depth×256, keyframe LIDAR_TOP, nearest wins
//!                 /lidar_dense.png     16-bit depth×256, ±K sweeps, occlusion-filtered
//!                 /lowheight_mask.png  8-bit, 255 where the sparse GT point is 0.3–2.0 m above ground
//!                 /radar_raw.png       16-bit depth×256, one pixel per radar point
//!                 /radar_height.png    16-bit depth×256, height-extended strips
//!                 /radar_points.bin    the radar returns behind both maps (`radar_points`)
//!                 /meta.json           SampleMeta
//! ```
//! A sample directory is complete iff `meta.json` exists: it is written last, and the
//! directory is first assembled under a temporary name and renamed into place. Every file's
//! coding, `radar_points.bin`'s byte layout included: docs/guide/deploy.md, "A prepared
//! sample's files".

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Training frame width (SPEC §3).
pub const FRAME_W: u32 = 800;
/// Training frame height (SPEC §3).
pub const FRAME_H: u32 = 350;
/// Full-resolution → training-frame scale.
pub const FRAME_SCALE: f64 = 0.5;
/// Rows cropped from the top of the half-resolution image.
pub const FRAME_CROP_TOP: u32 = 100;

pub const INDEX_FILE: &str = "index.json";
pub const IMAGE_FILE: &str = "image.png";
pub const LIDAR_SPARSE_FILE: &str = "lidar_sparse.png";
pub const LIDAR_DENSE_FILE: &str = "lidar_dense.png";
pub const LOWHEIGHT_MASK_FILE: &str = "lowheight_mask.png";
pub const RADAR_RAW_FILE: &str = "radar_raw.png";
pub const RADAR_HEIGHT_FILE: &str = "radar_height.png";
pub const META_FILE: &str = "meta.json";
/// Written into a sample folder by `depthsense mer apply` (SPEC §5), not by `prepare`.
pub const MER_DEPTH_FILE: &str = "radar_mer_depth.png";
pub const MER_CONF_FILE: &str = "radar_mer_conf.png";

/// Scene condition derived from the lower-cased scene description (SPEC §2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Condition {
    Day,
    Night,
    Rain,
}

/// Conditions of a scene: "night" and/or "rain" in its description, else day.
/// A scene that is both night and rain belongs to both rows (splits/README).
pub fn conditions_of(description: &str) -> Vec<Condition> {
    // Whole words only (issue 10): "train", "terrain" and "drain" are not rain.
    let words: Vec<String> = description
        .split(|c: char| !c.is_alphanumeric())
        .filter(|w| !w.is_empty())
        .map(str::to_lowercase)
        .collect();
    let has = |w: &str| words.iter().any(|x| x == w);
    let mut out = Vec::new();
    if has("night") {
        out.push(Condition::Night);
    }
    if has("rain") {
        out.push(Condition::Rain);
    }
    if out.is_empty() {
        out.push(Condition::Day);
    }
    out
}

/// Everything `train`/`eval` need to know about one prepared sample besides the maps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SampleMeta {
    pub sample_token: String,
    pub scene_token: String,
    pub scene_name: String,
    /// Conditions of the scene (usually one; night+rain scenes carry both).
    pub conditions: Vec<Condition>,
    pub timestamp_us: i64,
    /// sample_data tokens used: "CAM_FRONT", "LIDAR_TOP", "RADAR_FRONT", … → token of the keyframe.
    pub sample_data_tokens: BTreeMap<String, String>,
    /// Training-frame intrinsics, row-major 3x3 (fx, fy, cx, cy already ×0.5 and cy −100).
    pub intrinsics_frame: [[f64; 3]; 3],
    /// Full-resolution intrinsics from calibrated_sensor, row-major 3x3.
    pub intrinsics_full: [[f64; 3]; 3],
    /// 4x4 row-major camera_from_lidar transform (keyframe sweep, both ego poses applied).
    pub cam_from_lidar: [[f64; 4]; 4],
    /// Per radar channel, 4x4 row-major camera_from_radar of its keyframe sweep.
    pub cam_from_radar: BTreeMap<String, [[f64; 4]; 4]>,
    /// Counts: "lidar_points", "lidar_in_image", "lidar_dense_pixels", "radar_points",
    /// "radar_in_image", "radar_filtered_out", "nan_dropped", …
    pub counts: BTreeMap<String, u64>,
    /// Preparation settings that produced the maps (sweeps, channels, filters, K …).
    pub settings: serde_json::Value,
}

/// One line of `index.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IndexEntry {
    pub sample_token: String,
    pub scene_token: String,
    pub scene_name: String,
    /// Split names this sample belongs to (e.g. ["train", "official-train"], ["val"],
    /// ["test", "test-night"], or ["all"] when its scene is in no list). "train" and "val"
    /// never both appear.
    pub splits: Vec<String>,
    pub conditions: Vec<Condition>,
    /// Directory relative to the index file (normally the sample token).
    pub dir: String,
}

/// `O/index.json`: every prepared sample.
///
/// Split protocol: train on samples tagged "train", select checkpoints on "val", report on
/// "test" only. `IndexEntry::splits` carries the tags; the scene lists below say which
/// scenes of the version each of the three holds (whether prepared or not).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PreparedIndex {
    /// Dataset version folder the samples came from (e.g. "v1.0-mini", "v1.0-synth").
    pub version: String,
    pub samples: Vec<IndexEntry>,
    /// Where the split tags came from: `"dataroot: <dir>"` (the version's own
    /// `splits/{train,val,test}_scenes.txt`), `"shipped"` (the repository's lists, val = every
    /// 10th released-train scene per condition; see `splits`), or `""` (an index written
    /// before this field existed).
    #[serde(default)]
    pub split_source: String,
    /// Scene tokens of the version in train / val / test (table order).
    #[serde(default)]
    pub train_scenes: Vec<String>,
    #[serde(default)]
    pub val_scenes: Vec<String>,
    #[serde(default)]
    pub test_scenes: Vec<String>,
    /// The map settings every sample of this folder was prepared with (radar sweeps and
    /// channels, filters, K, dense-target rules; `pipeline::map_settings`), stored once: a run
    /// with other settings is refused. Empty in an index written before issue 10.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub settings: BTreeMap<String, serde_json::Value>,
    /// Set in a shard's own index (`index.shard-I-of-N.json`, see [`shard_index_file`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<ShardInfo>,
    /// [width, height] of every sample's maps ([`FRAME_W`] × [`FRAME_H`] for `prepare`), so that
    /// a network is sized without reading a sample. `None` in an index written before.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_size: Option<[u32; 2]>,
}

/// Which part of a sharded `prepare` an index holds.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardInfo {
    /// 0-based shard number I of `--shard I/N`.
    pub index: usize,
    /// N.
    pub count: usize,
    /// Scene tokens of this shard, in the order of the unsharded run (scene j of the selected
    /// scenes goes to shard j mod N).
    pub scenes: Vec<String>,
}

/// File name of shard `index` of `count` in the output folder: `index.shard-I-of-N.json`.
pub fn shard_index_file(index: usize, count: usize) -> String {
    format!("index.shard-{index}-of-{count}.json")
}

/// Lock file guarding `index.json` and the shard index files of an output folder.
pub const INDEX_LOCK_FILE: &str = ".index.lock";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conditions_follow_description_words() {
        assert_eq!(conditions_of("Night, parking lot"), vec![Condition::Night]);
        assert_eq!(conditions_of("RAIN, trucks"), vec![Condition::Rain]);
        assert_eq!(
            conditions_of("Night, rain, wet road"),
            vec![Condition::Night, Condition::Rain]
        );
        assert_eq!(conditions_of("Parked cars, peds"), vec![Condition::Day]);
    }

    #[test]
    fn condition_words_are_whole_words() {
        // issue 10 defect 6: substrings of other words are not conditions.
        assert_eq!(
            conditions_of("Pedestrians, train station"),
            vec![Condition::Day]
        );
        assert_eq!(conditions_of("Drain cover, terrain"), vec![Condition::Day]);
        assert_eq!(
            conditions_of("Brainstorm, nightclub, overnight parking"),
            vec![Condition::Day]
        );
        assert_eq!(
            conditions_of("Night, rain, parking lot"),
            vec![Condition::Night, Condition::Rain]
        );
        assert_eq!(
            conditions_of("Rain, night"),
            vec![Condition::Night, Condition::Rain]
        );
        assert_eq!(
            conditions_of("heavy rain; wet road (night)"),
            vec![Condition::Night, Condition::Rain]
        );
        assert_eq!(conditions_of("Rain-soaked road"), vec![Condition::Rain]);
        assert_eq!(conditions_of(""), vec![Condition::Day]);
    }

    #[test]
    fn old_index_without_split_fields_still_loads() {
        let old = r#"{"version": "v1.0-mini", "samples": [{"sample_token": "a",
            "scene_token": "b", "scene_name": "scene-0001", "splits": ["train"],
            "conditions": ["day"], "dir": "a"}]}"#;
        let idx: PreparedIndex = serde_json::from_str(old).unwrap();
        assert_eq!(idx.samples.len(), 1);
        assert!(idx.split_source.is_empty() && idx.val_scenes.is_empty());
    }

    #[test]
    fn condition_serialises_lowercase() {
        assert_eq!(
            serde_json::to_string(&Condition::Night).unwrap(),
            "\"night\""
        );
    }
}
