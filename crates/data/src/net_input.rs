//! What a network is fed for one input, without libtorch: the one path from a prepared sample,
//! a sample token of a dataroot or raw files (a CAM_FRONT JPEG, radar `.pcd` files and the
//! calibration JSON of [`depthsense_prep::calibration`]) to the host arrays of the network's
//! inputs ([`NetInputs`]). `depthsense predict` (`depthsense_eval::predict`) feeds its network
//! through here, and so does the Python module `depthsense` (`crates/python`), whose arrays go
//! to an exported graph: what a deployment feeds a model is what `predict` feeds it, bit for bit.
//!
//! The radar of raw files and tokens goes through `prepare`'s own function for every sweep
//! (`prep::pipeline::add_sweep`) and is stored as `prepare` stores it ([`as_stored`]: the
//! 16-bit PNG, depth × 256), so the three inputs of one keyframe give the same maps, bit for bit.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use depthsense_config::RadarInput;
use depthsense_dataset::{decode_rgb, read_depth, DataError};
use depthsense_nuscenes::depth_png::{decode_png, encode_png, DepthMap};
use depthsense_nuscenes::geometry::{Camera, Rigid};
use depthsense_prep::calibration::{Calibration, RadarEntry, RadarSettings};
use depthsense_prep::layout::{
    FRAME_H, FRAME_W, IMAGE_FILE, LIDAR_SPARSE_FILE, RADAR_HEIGHT_FILE, RADAR_RAW_FILE,
};
use depthsense_prep::maps::image_to_frame;
use depthsense_prep::pipeline::{add_sweep, velocity_dt_s, RadarSweep};
use depthsense_prep::radar_points::RadarPoints;

/// One network input in the training frame.
#[derive(Debug, Clone)]
pub struct PredictInput {
    pub name: String,
    pub image: image::RgbImage,
    pub radar_raw: DepthMap,
    pub radar_height: DepthMap,
    /// Sparse lidar GT when known (prepared sample / dataroot token).
    pub gt: Option<DepthMap>,
    /// MER (depth, confidence) maps (SPEC §5): read from a prepared sample where `mer apply`
    /// wrote them, or computed by `depthsense_eval::predict::attach_mer` (`--mer-checkpoint`).
    pub mer: Option<(DepthMap, DepthMap)>,
    /// How the radar of this input was gathered (sweeps, channels, filters, velocity
    /// compensation), when known: compared with the checkpoint's ([`radar_warnings`]).
    pub radar_settings: Option<RadarSettings>,
}

/// The host arrays of a network's inputs for one [`PredictInput`], channel-major.
#[derive(Debug, Clone, PartialEq)]
pub struct NetInputs {
    pub width: usize,
    pub height: usize,
    /// `[3, H, W]`, RGB in [0, 1]: each 8-bit value / 255 (the exported graph's `image`; the
    /// network itself takes [`NetInputs::normalised_image`]).
    pub image: Vec<f32>,
    /// `[C, H, W]` in metres, 0 = no return: the model's radar input (the exported graph's
    /// `radar`); empty (C = 0) for an RGB-only model.
    pub radar: Vec<f32>,
    pub radar_channels: usize,
}

impl NetInputs {
    /// The image as the network takes it: [`NetInputs::image`] less the ImageNet mean, over
    /// the ImageNet standard deviation (SPEC §6) — what an exported graph computes inside.
    pub fn normalised_image(&self) -> Vec<f32> {
        let plane = self.width * self.height;
        self.image
            .iter()
            .enumerate()
            .map(|(i, &x)| crate::normalise_value(x, i / plane))
            .collect()
    }
}

/// The network inputs of `input` for a model fed `radar` (None: RGB-only; ask the model's
/// config with `ModelConfig::radar_input_for`).
pub fn net_inputs(input: &PredictInput, radar: Option<RadarInput>) -> Result<NetInputs, DataError> {
    let (w, h) = input.image.dimensions();
    let (width, height) = (w as usize, h as usize);
    let image = crate::rgb01(&input.image);
    let radar_planes = match radar {
        None => vec![],
        Some(RadarInput::Mer) => {
            let (d, c) = input
                .mer
                .as_ref()
                .ok_or_else(|| DataError::InputWithoutMer {
                    input: input.name.clone(),
                })?;
            crate::radar_planes(
                RadarInput::Mer,
                &input.radar_raw,
                &input.radar_height,
                Some((&d.depth_m, &c.depth_m)),
            )
        }
        Some(r) => crate::radar_planes(r, &input.radar_raw, &input.radar_height, None),
    };
    let plane = width * height;
    if radar_planes.len() % plane.max(1) != 0 {
        return Err(DataError::RadarPlanesSize {
            input: input.name.clone(),
            image: (width, height),
        });
    }
    Ok(NetInputs {
        width,
        height,
        image,
        radar_channels: radar_planes.len() / plane.max(1),
        radar: radar_planes,
    })
}

/// Read a prepared sample directory.
pub fn input_from_prepared(dir: &Path) -> Result<PredictInput, DataError> {
    depthsense_dataset::check_sample_dir(dir)?;
    let gt_path = dir.join(LIDAR_SPARSE_FILE);
    let meta = depthsense_dataset::read_meta(dir)?;
    let settings: BTreeMap<String, serde_json::Value> =
        serde_json::from_value(meta.settings.clone()).unwrap_or_default();
    Ok(PredictInput {
        name: dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        image: decode_rgb(&dir.join(IMAGE_FILE))?,
        radar_raw: read_depth(&dir.join(RADAR_RAW_FILE))?,
        radar_height: read_depth(&dir.join(RADAR_HEIGHT_FILE))?,
        gt: if gt_path.exists() {
            Some(read_depth(&gt_path)?)
        } else {
            None
        },
        mer: if dir.join(depthsense_prep::layout::MER_DEPTH_FILE).exists() {
            Some(depthsense_dataset::mer_maps::read_mer_maps(dir)?)
        } else {
            None
        },
        radar_settings: RadarSettings::from_map(&settings),
    })
}

/// A map as `prepare` stores it and the loader reads it back: through the 16-bit PNG
/// (depth × 256, SPEC §3), so that a map computed here equals the prepared file bit for bit.
pub fn as_stored(map: DepthMap) -> Result<DepthMap, DataError> {
    let bytes = encode_png(&map)?;
    Ok(decode_png(&bytes, "radar map")?)
}

/// Run the `prepare` computation for one sample token of a dataroot (nothing is written); the
/// maps are those `prepare` with `opts` writes, bit for bit.
pub fn input_from_token(
    dataroot: &Path,
    version: &str,
    token: &str,
    opts: &depthsense_prep::PrepareOptions,
) -> Result<PredictInput, DataError> {
    let nu = depthsense_nuscenes::tables::NuScenes::load(dataroot, version)?;
    input_from_tables(&nu, token, opts)
}

/// [`input_from_token`] with the dataroot's tables already loaded (`predict` over a list of
/// tokens loads them once).
pub fn input_from_tables(
    nu: &depthsense_nuscenes::tables::NuScenes,
    token: &str,
    opts: &depthsense_prep::PrepareOptions,
) -> Result<PredictInput, DataError> {
    let want = depthsense_nuscenes::tables::Token::parse(token);
    let no_such_token = || DataError::NoSuchToken {
        dataroot: opts.dataroot.clone(),
        version: opts.version.clone(),
        token: token.to_string(),
    };
    let sample = nu
        .sample
        .iter()
        .find(|s| s.token == want)
        .ok_or_else(no_such_token)?;
    let maps = depthsense_prep::pipeline::compute_sample(nu, sample, opts).map_err(|e| {
        DataError::TokenPrepare {
            token: token.to_string(),
            source: Box::new(e),
        }
    })?;
    let image = image::RgbImage::from_raw(FRAME_W, FRAME_H, maps.image_rgb).ok_or_else(|| {
        DataError::FrameImage {
            sample: Some(token.to_string()),
        }
    })?;
    Ok(PredictInput {
        name: token.to_string(),
        image,
        radar_raw: as_stored(maps.radar_raw)?,
        radar_height: as_stored(maps.radar_height)?,
        gt: Some(as_stored(maps.lidar_sparse)?),
        mer: None,
        radar_settings: Some(RadarSettings::of(opts)),
    })
}

/// The calibration JSON at `path` (either form, [`depthsense_prep::calibration::read`]).
fn read_calibration(path: &Path) -> Result<Calibration, DataError> {
    depthsense_prep::calibration::read(path).map_err(|e| DataError::Calibration {
        path: path.to_path_buf(),
        source: Box::new(e),
    })
}

/// The radar files of `calib` that `files` names (by file name), or all of its files; in the
/// calibration's order (that of `prepare`).
fn chosen_entries<'a>(
    calibration: &Path,
    calib: &'a Calibration,
    files: &[PathBuf],
) -> Result<Vec<(&'a RadarEntry, PathBuf)>, DataError> {
    let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
    if files.is_empty() {
        return Ok(calib
            .radar
            .iter()
            .map(|e| (e, depthsense_prep::calibration::file_of(calibration, e)))
            .collect());
    }
    let mut chosen = vec![];
    for f in files {
        let i = calib
            .radar
            .iter()
            .position(|e| name(Path::new(&e.file)) == name(f))
            .ok_or_else(|| DataError::NoCalibrationEntry {
                calibration: calibration.to_path_buf(),
                file: name(f).unwrap_or_default(),
                entries: calib
                    .radar
                    .iter()
                    .filter_map(|e| name(Path::new(&e.file)))
                    .collect(),
            })?;
        chosen.push((i, f.clone()));
    }
    chosen.sort_by_key(|(i, _)| *i);
    Ok(chosen
        .into_iter()
        .map(|(i, f)| (&calib.radar[i], f))
        .collect())
}

/// Build the input from raw files (see the module docs and docs/guide/deploy.md for the
/// calibration JSON): the radar goes through `prepare`'s own sweep function and storage, so
/// that a calibration written by `depthsense calibration` gives the prepared maps bit for bit.
/// `radar_files` empty: every file the calibration lists.
pub fn input_from_raw(
    jpeg: &Path,
    radar_files: &[PathBuf],
    calibration: &Path,
    radar_filters: bool,
) -> Result<PredictInput, DataError> {
    let calib = read_calibration(calibration)?;
    let full = decode_rgb(jpeg)?;
    let name = jpeg
        .file_stem()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    input_from_decoded(
        full,
        &jpeg.display().to_string(),
        name,
        radar_files,
        (calibration, &calib),
        radar_filters,
    )
}

/// [`input_from_raw`] with the camera image given as its file's bytes (JPEG, or any format
/// the `image` crate reads, decoded as [`input_from_raw`] decodes a file); `name` names it.
pub fn input_from_raw_bytes(
    image_bytes: &[u8],
    name: &str,
    radar_files: &[PathBuf],
    calibration: &Path,
    radar_filters: bool,
) -> Result<PredictInput, DataError> {
    let calib = read_calibration(calibration)?;
    let full = depthsense_dataset::maps::decode_rgb_bytes(image_bytes, Path::new(name))?;
    input_from_decoded(
        full,
        name,
        name.to_string(),
        radar_files,
        (calibration, &calib),
        radar_filters,
    )
}

fn input_from_decoded(
    full: image::RgbImage,
    label: &str,
    name: String,
    radar_files: &[PathBuf],
    (calibration, calib): (&Path, &Calibration),
    radar_filters: bool,
) -> Result<PredictInput, DataError> {
    let (w, h) = full.dimensions();
    let frame = image_to_frame(full.as_raw(), w, h).ok_or_else(|| DataError::NotCamFront {
        input: label.to_string(),
        size: (w, h),
    })?;
    let image = image::RgbImage::from_raw(FRAME_W, FRAME_H, frame)
        .ok_or(DataError::FrameImage { sample: None })?;
    let cam = Camera::from_intrinsic(&calib.camera_intrinsic, w, h);
    let filters = radar_filters && calib.settings.radar_filters;
    let velocity = calib.settings.radar_velocity_compensation;
    let mut points = RadarPoints::new(cam);
    let mut sweeps: BTreeMap<String, usize> = BTreeMap::new();
    for (e, path) in chosen_entries(calibration, calib, radar_files)? {
        let scan = depthsense_nuscenes::pcd::read_radar_pcd(&path)?;
        let dt_s = match (velocity, calib.camera_timestamp_us, e.timestamp_us) {
            (true, Some(c), Some(s)) => Some(velocity_dt_s(c, s)),
            _ => None,
        };
        let tf = Rigid::from_mat4(&e.cam_from_radar);
        let sweep = RadarSweep {
            channel: &e.channel,
            index: e.sweep,
            cam_from_radar: &tf,
            dt_s,
        };
        add_sweep(&mut points, &sweep, &scan, filters);
        *sweeps.entry(e.channel.clone()).or_default() += 1;
    }
    let maps = points.rasterise();
    Ok(PredictInput {
        name,
        image,
        radar_raw: as_stored(maps.raw.to_depth_map())?,
        radar_height: as_stored(maps.height.to_depth_map())?,
        gt: None,
        mer: None,
        radar_settings: Some(RadarSettings {
            radar_sweeps: sweeps.values().copied().min().unwrap_or(0),
            radar_channels: sweeps.keys().cloned().collect(),
            radar_filters: filters,
            radar_velocity_compensation: velocity && calib.camera_timestamp_us.is_some(),
        }),
    })
}

/// The radar settings a checkpoint's training data was prepared with (recorded by `train` in
/// the checkpoint, or in an export sidecar), when known.
pub fn trained_radar_settings(extra: &serde_json::Value) -> Option<RadarSettings> {
    let m = extra
        .get("train_state")
        .and_then(|s| s.get("data_settings"))
        .or_else(|| extra.get("data_settings"))?;
    RadarSettings::from_map(&serde_json::from_value(m.clone()).ok()?)
}

/// One warning per way the input's radar differs from training's (empty when either is
/// unknown): a model fed fewer sweeps or other filters than it was trained on is silently worse.
pub fn radar_warnings(trained: Option<&RadarSettings>, input: &PredictInput) -> Vec<String> {
    let (Some(t), Some(i)) = (trained, input.radar_settings.as_ref()) else {
        return vec![];
    };
    t.differences(i)
        .into_iter()
        .map(|d| {
            format!(
                "warning: {}: this input's radar has {d}; the model sees another radar than \
                 in training (a calibration written by `depthsense calibration` lists every \
                 sweep: docs/guide/deploy.md, \"Raw files\")",
                input.name
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(w: u32, h: u32) -> PredictInput {
        let image = image::RgbImage::from_fn(w, h, |x, y| {
            image::Rgb([(x * 37 + y) as u8, (y * 91 + x * 3) as u8, (x ^ y) as u8])
        });
        let map = |seed: u32| DepthMap {
            width: w,
            height: h,
            depth_m: (0..w * h)
                .map(|i| {
                    if (i * 7 + seed).is_multiple_of(11) {
                        1.0 + (i % 50) as f32 / 4.0
                    } else {
                        0.0
                    }
                })
                .collect(),
        };
        PredictInput {
            name: "t".into(),
            image,
            radar_raw: map(1),
            radar_height: map(2),
            gt: None,
            mer: None,
            radar_settings: None,
        }
    }

    /// What `predict` feeds its network is what training's loader normalises, bit for bit.
    #[test]
    fn the_network_image_is_the_loaders_bit_for_bit() {
        let inp = input(13, 7);
        let x = net_inputs(&inp, Some(RadarInput::Height)).unwrap();
        let loader = crate::normalise_image(&inp.image, &crate::Augment::NONE);
        let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&x.normalised_image()), bits(&loader));
        assert_eq!(x.image[0], inp.image.get_pixel(0, 0).0[0] as f32 / 255.0);
        assert_eq!(
            x.image[13 * 7],
            inp.image.get_pixel(0, 0).0[1] as f32 / 255.0
        );
    }

    /// A model fed MER radar refuses an input without MER maps, naming the input.
    #[test]
    fn a_mer_model_refuses_an_input_without_mer_maps() {
        let e = net_inputs(&input(5, 4), Some(RadarInput::Mer)).unwrap_err();
        assert!(matches!(&e, DataError::InputWithoutMer { input } if input == "t"));
        assert_eq!(
            e.to_string(),
            "configuration: t: the model takes MER radar (SPEC §5) but the input has no MER \
             maps: run `depthsense mer apply` on the prepared data or pass --mer-checkpoint"
        );
    }

    #[test]
    fn radar_planes_follow_the_radar_input() {
        let inp = input(5, 4);
        let n = 20;
        let none = net_inputs(&inp, None).unwrap();
        assert_eq!((none.radar_channels, none.radar.len()), (0, 0));
        let h = net_inputs(&inp, Some(RadarInput::Height)).unwrap();
        assert_eq!(h.radar, inp.radar_height.depth_m);
        let rh = net_inputs(&inp, Some(RadarInput::RawHeight)).unwrap();
        assert_eq!(rh.radar_channels, 2);
        assert_eq!(rh.radar[..n], inp.radar_raw.depth_m[..]);
        assert_eq!(rh.radar[n..], inp.radar_height.depth_m[..]);
        let err = net_inputs(&inp, Some(RadarInput::Mer)).unwrap_err();
        assert!(err.to_string().contains("no MER maps"), "{err}");
        let mut with_mer = inp.clone();
        with_mer.mer = Some((inp.radar_raw.clone(), inp.radar_raw.clone()));
        let mer = net_inputs(&with_mer, Some(RadarInput::Mer)).unwrap();
        assert_eq!(mer.radar_channels, 7);
    }
}
