//! `depthsense inspect`: JSON summaries of sensor files and version folders, and of
//! depthsense's own outputs: a prepared folder, a prepared sample folder, a 16-bit depth PNG
//! (prepared maps, `predict`'s depth.png), `radar_points.bin` and JSON files (tables).

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
/// no filters), an image, a 16-bit depth PNG (valid pixels, depth range), `radar_points.bin`,
/// a JSON file, a version folder (row counts, scenes with conditions), a prepared folder
/// (version, samples, splits, settings) or a prepared sample folder (every file summarised).
pub fn inspect(path: &Path) -> Result<Value, PrepError> {
    let name = path.display().to_string();
    if path.is_dir() {
        if is_prepared_sample(path) {
            return inspect_prepared_sample(path, name);
        }
        if is_prepared_folder(path) {
            return inspect_prepared_folder(path, name);
        }
        return inspect_version(path, name);
    }
    let bytes = std::fs::read(path).map_err(|e| NuError::io(path, e))?;
    let lower = name.to_lowercase();
    if lower.ends_with(crate::radar_points::RADAR_POINTS_FILE) {
        return inspect_radar_points(path, name, &bytes);
    }
    if lower.ends_with(".pcd.bin") || lower.ends_with(".bin") {
        return inspect_lidar_bin(name, &bytes);
    }
    if lower.ends_with(".pcd") {
        return inspect_pcd(name, &bytes);
    }
    if lower.ends_with(".json") {
        return inspect_json(name, &bytes);
    }
    inspect_image(name, &bytes)
}

/// An image; a 16-bit grey PNG is a depth map (depth × 256, 0 = none, SPEC §3).
fn inspect_image(name: String, bytes: &[u8]) -> Result<Value, PrepError> {
    let img = image::load_from_memory(bytes).map_err(|e| NuError::Image {
        path: name.clone(),
        reason: e.to_string(),
    })?;
    if img.color() == image::ColorType::L16 {
        let map = depthsense_nuscenes::depth_png::decode_png(bytes, &name)?;
        return Ok(depth_summary(name, &map));
    }
    Ok(
        json!({"path": name, "kind": "image", "width": img.width(), "height": img.height(), "color": format!("{:?}", img.color())}),
    )
}

/// A depth map's size, valid pixels and depth range (metres).
fn depth_summary(name: String, map: &depthsense_nuscenes::depth_png::DepthMap) -> Value {
    let valid = map.depth_m.iter().filter(|d| **d > 0.0);
    let mut o = stats("depth_m", "F32", valid.map(|d| *d as f64));
    let obj = o.as_object_mut().expect("stats is an object");
    obj.remove("name");
    obj.remove("type");
    json!({
        "path": name,
        "kind": "depth_png",
        "width": map.width,
        "height": map.height,
        "valid_pixels": map.valid_count(),
        "valid_fraction": map.valid_count() as f64 / (map.width as f64 * map.height as f64).max(1.0),
        "depth_m": o,
    })
}

/// `radar_points.bin`: the returns behind a sample's radar maps, per channel and sweep.
fn inspect_radar_points(path: &Path, name: String, bytes: &[u8]) -> Result<Value, PrepError> {
    let p = crate::radar_points::RadarPoints::decode(bytes, path)?;
    let groups: Vec<Value> = p
        .groups
        .iter()
        .map(|g| {
            json!({
                "channel": p.channels.get(g.channel as usize),
                "sweep": g.sweep,
                "points": g.n_points,
            })
        })
        .collect();
    Ok(json!({
        "path": name,
        "kind": "radar_points",
        "points": p.points_cam.len(),
        "channels": p.channels,
        "groups": groups,
    }))
}

/// A JSON file: an evaluation's tables (each model's headline row), else its top-level keys.
fn inspect_json(name: String, bytes: &[u8]) -> Result<Value, PrepError> {
    let v: Value = serde_json::from_slice(bytes).map_err(|e| {
        PrepError::Nu(NuError::Json {
            path: name.clone(),
            reason: e.to_string(),
        })
    })?;
    if let Some(models) = v.get("models").and_then(Value::as_array) {
        let summary: Vec<Value> = models.iter().map(headline_of).collect();
        return Ok(json!({"path": name, "kind": "tables", "models": summary}));
    }
    let keys: Vec<&String> = v
        .as_object()
        .map(|o| o.keys().collect())
        .unwrap_or_default();
    Ok(json!({"path": name, "kind": "json", "keys": keys}))
}

/// A model of `tables.json`: its name, images and the combined, full-image row at the largest
/// cap.
fn headline_of(m: &Value) -> Value {
    let rows = m
        .get("report")
        .and_then(|r| r.get("rows"))
        .or_else(|| m.get("rows"))
        .and_then(Value::as_array);
    let head = rows.and_then(|rows| {
        rows.iter()
            .filter(|r| r["condition"] == "combined" && r["region"] == "full")
            .max_by(|a, b| {
                let cap = |r: &Value| r["cap_m"].as_f64().unwrap_or(0.0);
                cap(a).total_cmp(&cap(b))
            })
    });
    json!({
        "name": m.get("name"),
        "headline": head.map(|r| json!({
            "cap_m": r["cap_m"],
            "images": r["n_images"],
            "rmse_m": r["metrics"]["rmse"],
            "mae_m": r["metrics"]["mae"],
            "abs_rel": r["metrics"]["abs_rel"],
            "delta1": r["metrics"]["delta1"],
        })),
    })
}

/// Whether `dir` is one sample folder of a prepared folder (it holds `meta.json`).
pub fn is_prepared_sample(dir: &Path) -> bool {
    dir.join(crate::layout::META_FILE).is_file()
}

/// Whether `dir` is a prepared folder (it holds `index.json` or shard indexes).
pub fn is_prepared_folder(dir: &Path) -> bool {
    dir.join(crate::layout::INDEX_FILE).is_file()
}

/// A prepared sample folder: meta.json's sample, conditions, counts and settings, and every
/// map and file in it summarised.
fn inspect_prepared_sample(dir: &Path, name: String) -> Result<Value, PrepError> {
    let meta_path = dir.join(crate::layout::META_FILE);
    let meta: crate::layout::SampleMeta =
        serde_json::from_slice(&std::fs::read(&meta_path).map_err(|e| NuError::io(&meta_path, e))?)
            .map_err(|e| {
                PrepError::Nu(NuError::Json {
                    path: meta_path.display().to_string(),
                    reason: e.to_string(),
                })
            })?;
    let mut files = vec![];
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .map_err(|e| NuError::io(dir, e))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file() && p.file_name().is_some_and(|n| n != crate::layout::META_FILE))
        .collect();
    entries.sort();
    for p in entries {
        let file = p.file_name().map(|n| n.to_string_lossy().into_owned());
        files.push(match inspect(&p) {
            Ok(mut v) => {
                v["path"] = json!(file);
                v
            }
            Err(e) => json!({"path": file, "error": e.to_string()}),
        });
    }
    Ok(json!({
        "path": name,
        "kind": "prepared_sample",
        "sample_token": meta.sample_token,
        "scene_name": meta.scene_name,
        "conditions": meta.conditions,
        "counts": meta.counts,
        "settings": meta.settings,
        "files": files,
    }))
}

/// A prepared folder: its version, samples per split and condition, and the map settings.
fn inspect_prepared_folder(dir: &Path, name: String) -> Result<Value, PrepError> {
    let p = dir.join(crate::layout::INDEX_FILE);
    let ix: crate::layout::PreparedIndex = serde_json::from_slice(
        &std::fs::read(&p).map_err(|e| NuError::io(&p, e))?,
    )
    .map_err(|e| {
        PrepError::Nu(NuError::Json {
            path: p.display().to_string(),
            reason: e.to_string(),
        })
    })?;
    let mut splits: std::collections::BTreeMap<&str, usize> = Default::default();
    let mut conditions: std::collections::BTreeMap<String, usize> = Default::default();
    for s in &ix.samples {
        for sp in &s.splits {
            *splits.entry(sp.as_str()).or_default() += 1;
        }
        for c in &s.conditions {
            *conditions
                .entry(format!("{c:?}").to_lowercase())
                .or_default() += 1;
        }
    }
    Ok(json!({
        "path": name,
        "kind": "prepared",
        "version": ix.version,
        "samples": ix.samples.len(),
        "splits": splits,
        "conditions": conditions,
        "split_source": ix.split_source,
        "settings": ix.settings,
    }))
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
        if p.is_dir() && !is_version_folder(p) && !is_prepared_sample(p) && !is_prepared_folder(p) {
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
