//! `depthsense inspect`: JSON summaries of sensor files and version folders.

use std::path::Path;

use depthsense_nuscenes::pcd::{parse_pcd, PcdData};
use depthsense_nuscenes::tables::NuScenes;
use depthsense_nuscenes::NuError;
use serde_json::{json, Value};

use crate::error::PrepError;
use crate::layout::conditions_of;

fn stats(name: &str, ty: &str, vals: impl Iterator<Item = f64>) -> Value {
    let (mut min, mut max, mut sum, mut n, mut nonfinite) =
        (f64::INFINITY, f64::NEG_INFINITY, 0.0, 0u64, 0u64);
    for v in vals {
        if !v.is_finite() {
            nonfinite += 1;
            continue;
        }
        min = min.min(v);
        max = max.max(v);
        sum += v;
        n += 1;
    }
    let f = |v: f64| if n > 0 { json!(v) } else { Value::Null };
    let mut o = json!({"name": name, "type": ty, "min": f(min), "max": f(max), "mean": f(sum / n.max(1) as f64)});
    if nonfinite > 0 {
        o["non_finite"] = json!(nonfinite);
    }
    o
}

/// Summary of `path`: a point cloud (`points`, `fields` with min/max/mean over all points,
/// no filters), an image, or a version folder (row counts, scenes with conditions).
pub fn inspect(path: &Path) -> Result<Value, PrepError> {
    let name = path.display().to_string();
    if path.is_dir() {
        return inspect_version(path, name);
    }
    let bytes = std::fs::read(path).map_err(|e| NuError::io(path, e))?;
    let lower = name.to_lowercase();
    if lower.ends_with(".pcd.bin") || lower.ends_with(".bin") {
        return inspect_lidar_bin(name, &bytes);
    }
    if lower.ends_with(".pcd") {
        return inspect_pcd(name, &bytes);
    }
    let img = image::load_from_memory(&bytes).map_err(|e| NuError::Image {
        path: name.clone(),
        reason: e.to_string(),
    })?;
    Ok(
        json!({"path": name, "kind": "image", "width": img.width(), "height": img.height(), "color": format!("{:?}", img.color())}),
    )
}

/// Whether `dir` is a nuScenes version folder (it holds `scene.json`).
pub fn is_version_folder(dir: &Path) -> bool {
    dir.join("scene.json").is_file()
}

/// Whether `inspect` reads `path` as a sensor file (by its name).
pub fn is_sensor_file(path: &Path) -> bool {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    [".pcd", ".bin", ".jpg", ".jpeg", ".png"]
        .iter()
        .any(|ext| name.ends_with(ext))
}

/// What `inspect PATH...` reads: each file as given; a version folder as one; any other folder
/// as its sensor files ([`is_sensor_file`]), recursively, sorted by path.
pub fn expand_paths(paths: &[std::path::PathBuf]) -> Result<Vec<std::path::PathBuf>, PrepError> {
    let mut out = vec![];
    for p in paths {
        if p.is_dir() && !is_version_folder(p) {
            let mut found = vec![];
            collect_sensor_files(p, &mut found)?;
            found.sort();
            out.extend(found);
        } else {
            out.push(p.clone());
        }
    }
    Ok(out)
}

fn collect_sensor_files(dir: &Path, out: &mut Vec<std::path::PathBuf>) -> Result<(), PrepError> {
    let entries = std::fs::read_dir(dir).map_err(|e| NuError::io(dir, e))?;
    for e in entries {
        let path = e.map_err(|e| NuError::io(dir, e))?.path();
        if path.is_dir() {
            collect_sensor_files(&path, out)?;
        } else if is_sensor_file(&path) {
            out.push(path);
        }
    }
    Ok(())
}

/// [`inspect`] of every path, in order, on all cores: a failure stays with its path.
pub fn inspect_all(paths: &[std::path::PathBuf]) -> Vec<Result<Value, PrepError>> {
    use rayon::prelude::*;
    paths.par_iter().map(|p| inspect(p)).collect()
}

/// A version folder: row counts and the scenes with their conditions.
fn inspect_version(path: &Path, name: String) -> Result<Value, PrepError> {
    let version = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let root = path.parent().unwrap_or(Path::new("."));
    let nu = NuScenes::load(root, &version)?;
    let tables: serde_json::Map<String, Value> = nu
        .row_counts()
        .into_iter()
        .map(|(k, v)| (k.to_string(), json!(v)))
        .collect();
    let scenes: Vec<Value> = nu
        .scene
        .iter()
        .map(|s| {
            json!({
                "token": s.token.to_string(),
                "name": s.name,
                "description": s.description,
                "conditions": conditions_of(&s.description),
                "samples": nu.scene_samples(s.token).len(),
            })
        })
        .collect();
    Ok(
        json!({"path": name, "kind": "version", "version": version, "tables": tables, "scenes": scenes}),
    )
}

/// A lidar `.pcd.bin` (5 float32 per point): the statistics of each field.
fn inspect_lidar_bin(name: String, bytes: &[u8]) -> Result<Value, PrepError> {
    if !bytes.len().is_multiple_of(20) {
        return Err(NuError::Pcd {
            path: name,
            reason: format!(
                "length {} is not a multiple of 20 bytes (5 float32 per point)",
                bytes.len()
            ),
        }
        .into());
    }
    let n = bytes.len() / 20;
    let val = |p: usize, k: usize| {
        let o = p * 20 + 4 * k;
        f32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]) as f64
    };
    let fields: Vec<Value> = ["x", "y", "z", "intensity", "ring"]
        .iter()
        .enumerate()
        .map(|(k, f)| stats(f, "F32", (0..n).map(|p| val(p, k))))
        .collect();
    Ok(json!({"path": name, "kind": "lidar_pcd_bin", "points": n, "fields": fields}))
}

/// A `.pcd` file: its data encoding, point count and the statistics of each field column.
fn inspect_pcd(name: String, bytes: &[u8]) -> Result<Value, PrepError> {
    let c = parse_pcd(bytes, &name)?;
    let mut fields = Vec::new();
    let mut col = 0;
    for f in &c.header.fields {
        let ty = format!(
            "{}{}",
            match f.ty {
                'F' => "F",
                'I' => "I",
                _ => "U",
            },
            f.size * 8
        );
        for _ in 0..f.count {
            fields.push(stats(&c.names[col], &ty, c.columns[col].iter().copied()));
            col += 1;
        }
    }
    let data = match c.header.data {
        PcdData::Ascii => "ascii",
        PcdData::Binary => "binary",
        PcdData::BinaryCompressed => "binary_compressed",
    };
    Ok(
        json!({"path": name, "kind": "pcd", "data": data, "points": c.header.points, "fields": fields}),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inspect_pcd_and_folder() {
        let Some(root) = depthsense_testkit::fixture("nuscenes-kf0") else {
            return;
        };
        let r = inspect(&root.join(
            "samples/RADAR_FRONT/n015-2018-07-24-11-22-45+0800__RADAR_FRONT__1532402927664178.pcd",
        ))
        .unwrap();
        assert_eq!(r["points"], 125);
        assert_eq!(r["fields"].as_array().unwrap().len(), 18);
        assert_eq!(r["fields"][2]["name"], "z");
        assert_eq!(r["fields"][2]["max"], 0.0);
        assert_eq!(r["fields"][4]["type"], "I16");
        let l = inspect(&root.join(
            "samples/LIDAR_TOP/n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927647951.pcd.bin",
        ))
        .unwrap();
        assert_eq!(l["points"], 34688);
        assert!(l["fields"][4]["max"].as_f64().unwrap() <= 31.0);
        let v = inspect(&root.join("v1.0-mini")).unwrap();
        assert_eq!(v["tables"]["sample_data"], 3);
        assert_eq!(v["scenes"][0]["conditions"], json!(["day"]));
        let i = inspect(&root.join(
            "samples/CAM_FRONT/n015-2018-07-24-11-22-45+0800__CAM_FRONT__1532402927612460.jpg",
        ))
        .unwrap();
        assert_eq!(
            (i["width"].as_u64(), i["height"].as_u64()),
            (Some(1600), Some(900))
        );
    }
}
