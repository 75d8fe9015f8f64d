//! `prepare --verify`: re-read every file of a prepared sample folder (the on-disk contract of
//! [`crate::layout`]) so that a truncated or corrupt sample — a disk error, a copy cut short —
//! is found, removed and prepared again instead of stopping `train`, `eval` or `predict`.

use std::path::Path;

use depthsense_nuscenes::depth_png::decode_png;

use crate::layout::{
    SampleMeta, FRAME_H, FRAME_W, IMAGE_FILE, LIDAR_DENSE_FILE, LIDAR_SPARSE_FILE,
    LOWHEIGHT_MASK_FILE, MER_CONF_FILE, MER_DEPTH_FILE, META_FILE, RADAR_HEIGHT_FILE,
    RADAR_RAW_FILE,
};
use crate::radar_points::{RadarPoints, RADAR_POINTS_FILE};

/// The 16-bit depth maps every sample has, then those it may have (older folders, `mer apply`).
const DEPTH_MAPS: &[&str] = &[LIDAR_SPARSE_FILE, RADAR_RAW_FILE, RADAR_HEIGHT_FILE];
const OPTIONAL_DEPTH_MAPS: &[&str] = &[LIDAR_DENSE_FILE, MER_DEPTH_FILE, MER_CONF_FILE];

/// Every file of sample folder `dir` decodes and has the training frame's size; the first
/// problem as `file: what` otherwise.
pub fn verify_sample(dir: &Path) -> Result<(), String> {
    let read = |name: &str| {
        let p = dir.join(name);
        std::fs::read(&p).map_err(|e| format!("{}: {e}", p.display()))
    };
    let meta = read(META_FILE)?;
    serde_json::from_slice::<SampleMeta>(&meta)
        .map_err(|e| format!("{}: {e}", dir.join(META_FILE).display()))?;
    for name in [IMAGE_FILE, LOWHEIGHT_MASK_FILE] {
        let p = dir.join(name);
        if name == LOWHEIGHT_MASK_FILE && !p.exists() {
            continue;
        }
        let img =
            image::load_from_memory(&read(name)?).map_err(|e| format!("{}: {e}", p.display()))?;
        frame_size(&p, img.width(), img.height())?;
    }
    for name in DEPTH_MAPS.iter().chain(OPTIONAL_DEPTH_MAPS) {
        let p = dir.join(name);
        if !p.exists() && OPTIONAL_DEPTH_MAPS.contains(name) {
            continue;
        }
        let map = decode_png(&read(name)?, &p.display().to_string()).map_err(|e| e.to_string())?;
        frame_size(&p, map.width, map.height)?;
    }
    let points = dir.join(RADAR_POINTS_FILE);
    if points.exists() {
        RadarPoints::decode(&read(RADAR_POINTS_FILE)?, &points).map_err(|e| e.to_string())?;
    }
    Ok(())
}

fn frame_size(p: &Path, w: u32, h: u32) -> Result<(), String> {
    if (w, h) == (FRAME_W, FRAME_H) {
        Ok(())
    } else {
        Err(format!(
            "{}: {w}x{h}, not the {FRAME_W}x{FRAME_H} training frame",
            p.display()
        ))
    }
}

/// Whether `dir` holds maps that `depthsense mer apply` wrote (lost when the sample is
/// prepared again).
pub fn has_mer_maps(dir: &Path) -> bool {
    dir.join(MER_DEPTH_FILE).exists()
}
