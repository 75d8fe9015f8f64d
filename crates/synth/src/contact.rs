//! Contact sheet of a dataroot: one keyframe per condition (day / night / rain) in columns;
//! rows: the image with projected LIDAR_TOP points, with projected radar points (all three
//! radars, 5 sweeps), and the exact truth depth. Points and depth are coloured by depth.

use std::path::Path;

use depthsense_nuscenes::depth_png::read_depth_png;
use depthsense_nuscenes::pcd::{read_lidar_pcd_bin, read_radar_pcd};
use glam::DVec3;

use crate::calib::{IMG_H, IMG_W, RADAR_CHANNELS};
use crate::readback::{project, Dataroot};
use crate::{SynthError, TRUTH_DIR};

/// Tile size (1/4 of 1600x900).
const TW: u32 = 400;
const TH: u32 = 225;
const DEPTH_MAX_M: f64 = 60.0;

/// Turbo-like colour map (polynomial fit of Google's Turbo), x in [0, 1].
pub fn turbo(x: f64) -> [u8; 3] {
    let x = x.clamp(0.0, 1.0);
    let r = 0.13572138
        + x * (4.61539260
            + x * (-42.66032258 + x * (132.13108234 + x * (-152.94239396 + x * 59.28637943))));
    let g = 0.09140261
        + x * (2.19418839
            + x * (4.84296658 + x * (-14.18503333 + x * (4.27729857 + x * 2.82956604))));
    let b = 0.10667330
        + x * (12.64194608
            + x * (-60.58204836 + x * (110.36276771 + x * (-89.90310912 + x * 27.34824973))));
    let c = |v: f64| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    [c(r), c(g), c(b)]
}

fn depth_colour(d: f64) -> [u8; 3] {
    turbo((d / DEPTH_MAX_M).sqrt())
}

struct Tile {
    px: Vec<[u8; 3]>,
}

impl Tile {
    fn from_image(rgb: &image::RgbImage) -> Tile {
        let mut px = vec![[0u8; 3]; (TW * TH) as usize];
        let sx = rgb.width() / TW;
        let sy = rgb.height() / TH;
        for y in 0..TH {
            for x in 0..TW {
                let mut acc = [0u32; 3];
                for dy in 0..sy {
                    for dx in 0..sx {
                        let p = rgb.get_pixel(x * sx + dx, y * sy + dy);
                        for k in 0..3 {
                            acc[k] += p[k] as u32;
                        }
                    }
                }
                let n = sx * sy;
                px[(y * TW + x) as usize] =
                    [(acc[0] / n) as u8, (acc[1] / n) as u8, (acc[2] / n) as u8];
            }
        }
        Tile { px }
    }
    fn dim(&mut self, k: f32) {
        for p in &mut self.px {
            for c in p.iter_mut() {
                *c = (*c as f32 * k) as u8;
            }
        }
    }
    fn dot(&mut self, u: f64, v: f64, r: i64, c: [u8; 3]) {
        let x = (u / (IMG_W / TW) as f64) as i64;
        let y = (v / (IMG_H / TH) as f64) as i64;
        for dy in -r..=r {
            for dx in -r..=r {
                let (xx, yy) = (x + dx, y + dy);
                if xx >= 0 && yy >= 0 && xx < TW as i64 && yy < TH as i64 {
                    self.px[(yy * TW as i64 + xx) as usize] = c;
                }
            }
        }
    }
}

/// Write a contact sheet PNG of `dataroot` (version folder `version`) to `out_png`.
pub fn contact_sheet(dataroot: &Path, version: &str, out_png: &Path) -> Result<(), SynthError> {
    let d = Dataroot::load(dataroot, version)?;
    let mut columns = Vec::new();
    for want in ["day", "night", "rain"] {
        let scene = d.scenes.iter().find(|s| {
            let desc = s
                .get("description")
                .and_then(|v| v.as_str())
                .unwrap_or_default()
                .to_lowercase();
            match want {
                "night" => desc.contains("night"),
                "rain" => desc.contains("rain"),
                _ => !desc.contains("night") && !desc.contains("rain"),
            }
        });
        if let Some(s) = scene {
            columns.push(s.clone());
        }
    }
    if columns.is_empty() {
        return Err(SynthError::Data(format!(
            "{}: no scenes",
            dataroot.display()
        )));
    }
    let ncol = columns.len() as u32;
    let (w, h) = (TW * ncol, TH * 3);
    let mut sheet = image::RgbImage::new(w, h);
    for (ci, scene) in columns.iter().enumerate() {
        // Middle keyframe of the scene.
        let mut tok = scene
            .get("first_sample_token")
            .and_then(|v| v.as_str())
            .unwrap_or_default()
            .to_string();
        let n = scene
            .get("nbr_samples")
            .and_then(|v| v.as_u64())
            .unwrap_or(1) as usize;
        for _ in 0..n / 2 {
            let next = d
                .samples
                .get(&tok)
                .and_then(|s| s.get("next"))
                .and_then(|v| v.as_str())
                .unwrap_or_default();
            if next.is_empty() {
                break;
            }
            tok = next.to_string();
        }
        let kf = |ch: &str| {
            d.keyframe
                .get(&(tok.clone(), ch.to_string()))
                .cloned()
                .ok_or_else(|| SynthError::Data(format!("sample {tok} has no {ch} keyframe")))
        };
        let cam = kf("CAM_FRONT")?;
        let img_path = d.path(&cam)?;
        let img = image::open(&img_path)
            .map_err(|e| SynthError::Data(format!("{}: {e}", img_path.display())))?
            .to_rgb8();
        // Row 1: lidar.
        let mut t1 = Tile::from_image(&img);
        t1.dim(0.6);
        let lid = kf("LIDAR_TOP")?;
        let scan =
            read_lidar_pcd_bin(&d.path(&lid)?).map_err(|e| SynthError::Data(e.to_string()))?;
        let tf = d.cam_from_sensor(&lid, &cam)?;
        let mut pts = project(
            scan.points
                .iter()
                .map(|p| tf.apply(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))),
        );
        pts.sort_by(|a, b| b.2.total_cmp(&a.2));
        for (u, v, z) in pts {
            t1.dot(u, v, 0, depth_colour(z));
        }
        // Row 2: radar, 5 sweeps of the three radars, as short vertical bars.
        let mut t2 = Tile::from_image(&img);
        t2.dim(0.6);
        for ch in RADAR_CHANNELS {
            let mut sd = kf(ch)?;
            for _ in 0..5 {
                let scan =
                    read_radar_pcd(&d.path(&sd)?).map_err(|e| SynthError::Data(e.to_string()))?;
                let tf = d.cam_from_sensor(&sd, &cam)?;
                for (u, v, z) in project(
                    scan.points
                        .iter()
                        .map(|p| tf.apply(DVec3::new(p.x as f64, p.y as f64, 0.0))),
                ) {
                    let c = depth_colour(z);
                    t2.dot(u, v, 1, c);
                    t2.dot(u, v - 4.0 * (IMG_H / TH) as f64, 0, c);
                    t2.dot(u, v - 8.0 * (IMG_H / TH) as f64, 0, c);
                }
                let prev = d
                    .sample_data
                    .get(&sd)
                    .and_then(|r| r.get("prev"))
                    .and_then(|v| v.as_str())
                    .unwrap_or_default()
                    .to_string();
                if prev.is_empty() {
                    break;
                }
                sd = prev;
            }
        }
        // Row 3: truth depth.
        let truth = read_depth_png(&dataroot.join(TRUTH_DIR).join(format!("{cam}.png")))
            .map_err(|e| SynthError::Data(e.to_string()))?;
        let mut t3 = Tile {
            px: vec![[0u8; 3]; (TW * TH) as usize],
        };
        let s = IMG_W / TW;
        for y in 0..TH {
            for x in 0..TW {
                let z = truth.at(x * s + s / 2, y * s + s / 2) as f64;
                t3.px[(y * TW + x) as usize] = if z > 0.0 { depth_colour(z) } else { [0, 0, 0] };
            }
        }
        for (ri, t) in [t1, t2, t3].iter().enumerate() {
            for y in 0..TH {
                for x in 0..TW {
                    // Quantise to 6 bits per channel: keeps the PNG small.
                    let p = t.px[(y * TW + x) as usize];
                    let q = [p[0] & 0xFC, p[1] & 0xFC, p[2] & 0xFC];
                    sheet.put_pixel(ci as u32 * TW + x, ri as u32 * TH + y, image::Rgb(q));
                }
            }
        }
    }
    let mut buf = Vec::new();
    {
        use image::ImageEncoder;
        image::codecs::png::PngEncoder::new_with_quality(
            &mut buf,
            image::codecs::png::CompressionType::Best,
            image::codecs::png::FilterType::Adaptive,
        )
        .write_image(sheet.as_raw(), w, h, image::ExtendedColorType::Rgb8)
        .map_err(|e| SynthError::Encode(format!("contact sheet: {e}")))?;
    }
    depthsense_nuscenes::fsutil::write_atomic(out_png, &buf).map_err(|source| SynthError::Io {
        path: out_png.display().to_string(),
        source,
    })
}
