//! Contact sheet of a dataroot: one keyframe per condition (day / night / rain) in columns;
//! rows: the image with projected LIDAR_TOP points, with projected radar points (all three
//! radars, 5 sweeps), and the exact truth depth. Points and depth are coloured by depth.

use std::path::Path;

use depthsense_nuscenes::depth_png::read_depth_png;
use depthsense_nuscenes::geometry::{apply_f32, cam_from_sensor, Camera, Rigid};
use depthsense_nuscenes::pcd::{read_lidar_pcd_bin, read_radar_pcd};
use depthsense_nuscenes::tables::{SampleData, Scene};
use depthsense_nuscenes::{NuScenes, Token};

use crate::calib::{IMG_H, IMG_W, RADAR_CHANNELS};
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

/// Project sensor-frame points into the camera: (u, v, depth) of those kept by
/// [`Camera::project`] (SPEC §2), through the f32 copy of `cam_from_sensor` as `prep` does.
fn project(cam: &Camera, cam_from_sensor: &Rigid, pts: &[[f32; 3]]) -> Vec<(f64, f64, f64)> {
    let m = cam_from_sensor.to_f32();
    pts.iter()
        .filter_map(|p| cam.project(apply_f32(&m, *p)))
        .map(|(u, v, z)| (u as f64, v as f64, z as f64))
        .collect()
}

/// Write a contact sheet PNG of `dataroot` (version folder `version`) to `out_png`.
/// The dataroot is read with depthsense's own reader (`depthsense_nuscenes`).
pub fn contact_sheet(dataroot: &Path, version: &str, out_png: &Path) -> Result<(), SynthError> {
    let nu = NuScenes::load(dataroot, version)?;
    let columns = condition_scenes(&nu);
    if columns.is_empty() {
        return Err(SynthError::NoScenes {
            dataroot: dataroot.to_path_buf(),
        });
    }
    let ncol = columns.len() as u32;
    let (w, h) = (TW * ncol, TH * 3);
    let mut sheet = image::RgbImage::new(w, h);
    for (ci, scene) in columns.iter().enumerate() {
        let tiles = scene_tiles(&nu, dataroot, scene)?;
        for (ri, t) in tiles.iter().enumerate() {
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
        .map_err(|source| SynthError::ContactSheetPng { source })?;
    }
    depthsense_base::fsutil::write_atomic(out_png, &buf).map_err(|source| SynthError::Io {
        path: out_png.to_path_buf(),
        source,
    })
}

/// The first day, night and rain scene (by description), those that exist.
fn condition_scenes(nu: &NuScenes) -> Vec<&Scene> {
    let mut columns = Vec::new();
    for want in ["day", "night", "rain"] {
        let scene = nu.scene.iter().find(|s| {
            let desc = s.description.to_lowercase();
            match want {
                "night" => desc.contains("night"),
                "rain" => desc.contains("rain"),
                _ => !desc.contains("night") && !desc.contains("rain"),
            }
        });
        if let Some(s) = scene {
            columns.push(s);
        }
    }
    columns
}

/// The keyframe of channel `channel` of `sample`.
fn keyframe<'a>(
    nu: &'a NuScenes,
    sample: Token,
    channel: &'static str,
) -> Result<&'a SampleData, SynthError> {
    nu.keyframe(sample, channel)
        .ok_or(SynthError::NoKeyframe { sample, channel })
}

/// The three tiles (lidar, radar, truth depth) of the middle keyframe of `scene`.
fn scene_tiles(nu: &NuScenes, dataroot: &Path, scene: &Scene) -> Result<[Tile; 3], SynthError> {
    // Middle keyframe of the scene.
    let samples = nu.scene_samples(scene.token);
    let sample = samples
        .get((scene.nbr_samples as usize / 2).min(samples.len().saturating_sub(1)))
        .ok_or(SynthError::SceneWithoutSamples { scene: scene.token })?;
    let cam_sd = keyframe(nu, sample.token, "CAM_FRONT")?;
    let cam_cs = nu.get_calibrated_sensor(
        cam_sd.calibrated_sensor_token,
        "sample_data",
        cam_sd.token,
        "calibrated_sensor_token",
    )?;
    let k = cam_cs
        .camera_intrinsic
        .ok_or(SynthError::NoCameraIntrinsic {
            calibrated_sensor: cam_cs.token,
        })?;
    let cam = Camera::from_intrinsic(&k, IMG_W, IMG_H);
    let img_path = nu.path_of(cam_sd);
    let img = image::open(&img_path)
        .map_err(|source| SynthError::CameraImage {
            path: img_path,
            source,
        })?
        .to_rgb8();
    let t1 = lidar_tile(nu, &img, &cam, cam_sd, sample.token)?;
    let t2 = radar_tile(nu, &img, &cam, cam_sd, sample.token)?;
    let t3 = truth_tile(dataroot, cam_sd)?;
    Ok([t1, t2, t3])
}

/// Row 1: the image with the projected lidar points.
fn lidar_tile(
    nu: &NuScenes,
    img: &image::RgbImage,
    cam: &Camera,
    cam_sd: &SampleData,
    sample: Token,
) -> Result<Tile, SynthError> {
    let mut t1 = Tile::from_image(img);
    t1.dim(0.6);
    let lid = keyframe(nu, sample, "LIDAR_TOP")?;
    let scan = read_lidar_pcd_bin(&nu.path_of(lid))?;
    let xyz: Vec<[f32; 3]> = scan.points.iter().map(|p| [p[0], p[1], p[2]]).collect();
    let tf = cam_from_sensor(nu, lid, cam_sd)?;
    let mut pts = project(cam, &tf, &xyz);
    pts.sort_by(|a, b| b.2.total_cmp(&a.2));
    for (u, v, z) in pts {
        t1.dot(u, v, 0, depth_colour(z));
    }
    Ok(t1)
}

/// Row 2: radar, 5 sweeps of the three radars, as short vertical bars.
fn radar_tile(
    nu: &NuScenes,
    img: &image::RgbImage,
    cam: &Camera,
    cam_sd: &SampleData,
    sample: Token,
) -> Result<Tile, SynthError> {
    let mut t2 = Tile::from_image(img);
    t2.dim(0.6);
    for ch in RADAR_CHANNELS {
        for sd in nu.sweeps_back(keyframe(nu, sample, ch)?, 5) {
            let scan = read_radar_pcd(&nu.path_of(sd))?;
            let xyz: Vec<[f32; 3]> = scan.points.iter().map(|p| [p.x, p.y, 0.0]).collect();
            let tf = cam_from_sensor(nu, sd, cam_sd)?;
            for (u, v, z) in project(cam, &tf, &xyz) {
                let c = depth_colour(z);
                t2.dot(u, v, 1, c);
                t2.dot(u, v - 4.0 * (IMG_H / TH) as f64, 0, c);
                t2.dot(u, v - 8.0 * (IMG_H / TH) as f64, 0, c);
            }
        }
    }
    Ok(t2)
}

/// Row 3: truth depth.
fn truth_tile(dataroot: &Path, cam_sd: &SampleData) -> Result<Tile, SynthError> {
    let truth = read_depth_png(
        &dataroot
            .join(TRUTH_DIR)
            .join(format!("{}.png", cam_sd.token)),
    )
    .map_err(|source| SynthError::TruthMap { source })?;
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
    Ok(t3)
}
