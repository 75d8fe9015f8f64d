//! `depthsense predict`: depth for one input, from
//! - a prepared sample directory (`prepare` output),
//! - a sample token of a nuScenes-format dataroot (the `prepare` code runs for that sample,
//!   with the radar settings the checkpoint was trained on), or
//! - raw files: a 1600x900 CAM_FRONT JPEG, radar `.pcd` files and a calibration JSON
//!   ([`depthsense_prep::calibration`]: the camera intrinsics and, per radar file, its channel,
//!   sweep index, time and sweep-sensor → keyframe-camera transform; `depthsense calibration`
//!   writes one from a nuScenes sample). The radar goes through `prepare`'s own function for
//!   every sweep, so the three inputs of one keyframe give the same maps, bit for bit.
//!
//! Outputs: `depth.png` (16-bit, depth×256, SPEC §3), `depth_color.png` (turbo),
//! `radar_overlay.png` (radar points over the image), `image.png` (the 800x350 frame).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use depthsense_base::fsutil::write_atomic;
use depthsense_config::RadarInput;
use depthsense_data::{normalise_image, Augment};
use depthsense_dataset::{decode_rgb, read_depth};
use depthsense_model::DepthNet;
use depthsense_nuscenes::depth_png::{decode_png, encode_png, DepthMap};
use depthsense_nuscenes::geometry::{Camera, Rigid};
use depthsense_prep::calibration::{Calibration, RadarEntry, RadarSettings};
use depthsense_prep::layout::{
    FRAME_H, FRAME_W, IMAGE_FILE, INDEX_FILE, LIDAR_SPARSE_FILE, META_FILE, RADAR_HEIGHT_FILE,
    RADAR_RAW_FILE,
};
use depthsense_prep::maps::image_to_frame;
use depthsense_prep::pipeline::{add_sweep, velocity_dt_s, RadarSweep};
use depthsense_prep::radar_points::RadarPoints;
use tch::{Device, Kind, Tensor};

use depthsense_infer::NetError;

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
    /// wrote them, or computed by [`attach_mer`] (`--mer-checkpoint`).
    pub mer: Option<(DepthMap, DepthMap)>,
    /// How the radar of this input was gathered (sweeps, channels, filters, velocity
    /// compensation), when known: compared with the checkpoint's ([`radar_warnings`]).
    pub radar_settings: Option<RadarSettings>,
}

/// Read a prepared sample directory.
pub fn input_from_prepared(dir: &Path) -> Result<PredictInput, NetError> {
    if !dir.join(META_FILE).exists() {
        let d = dir.display();
        return Err(NetError::Other(if dir.join(INDEX_FILE).exists() {
            format!(
                "{d} is a prepared folder, not one sample: pass --sample {d}/<sample token> \
                 for one of its samples, or --data {d} for a split of them"
            )
        } else if dir.is_dir() {
            format!(
                "{d}: not a prepared sample folder (no {META_FILE}); --sample takes one \
                 PREPARED/<sample token> folder written by `depthsense prepare`"
            )
        } else {
            format!(
                "{d}: no such folder; --sample takes one PREPARED/<sample token> folder \
                 written by `depthsense prepare`"
            )
        }));
    }
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
pub fn as_stored(map: DepthMap) -> Result<DepthMap, NetError> {
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
) -> Result<PredictInput, NetError> {
    let nu = depthsense_nuscenes::tables::NuScenes::load(dataroot, version)?;
    let want = depthsense_nuscenes::tables::Token::parse(token);
    let sample = nu.sample.iter().find(|s| s.token == want).ok_or_else(|| {
        NetError::Data(format!(
            "{}/{version}: no sample with token {token}",
            dataroot.display()
        ))
    })?;
    let maps = depthsense_prep::pipeline::compute_sample(&nu, sample, opts)
        .map_err(|e| NetError::Data(format!("sample {token}: {e}")))?;
    let image = image::RgbImage::from_raw(FRAME_W, FRAME_H, maps.image_rgb)
        .ok_or_else(|| NetError::Data(format!("sample {token}: image has the wrong size")))?;
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

/// The radar files of `calib` that `files` names (by file name), or all of its files; in the
/// calibration's order (that of `prepare`).
fn chosen_entries<'a>(
    calibration: &Path,
    calib: &'a Calibration,
    files: &[PathBuf],
) -> Result<Vec<(&'a RadarEntry, PathBuf)>, NetError> {
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
            .ok_or_else(|| {
                NetError::Data(format!(
                    "{}: no cam_from_radar entry for radar file {:?} (entries: {:?}); write \
                     the calibration with `depthsense calibration`, which lists every sweep",
                    calibration.display(),
                    name(f).unwrap_or_default(),
                    calib
                        .radar
                        .iter()
                        .filter_map(|e| name(Path::new(&e.file)))
                        .collect::<Vec<_>>()
                ))
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
) -> Result<PredictInput, NetError> {
    let calib = depthsense_prep::calibration::read(calibration)?;
    let full = decode_rgb(jpeg)?;
    let (w, h) = full.dimensions();
    let frame = image_to_frame(full.as_raw(), w, h).ok_or_else(|| {
        NetError::Data(format!(
            "{}: image is {w}x{h}; a nuScenes CAM_FRONT image is 1600x900",
            jpeg.display()
        ))
    })?;
    let image = image::RgbImage::from_raw(FRAME_W, FRAME_H, frame)
        .ok_or_else(|| NetError::Data("frame has the wrong size".into()))?;
    let cam = Camera::from_intrinsic(&calib.camera_intrinsic, w, h);
    let filters = radar_filters && calib.settings.radar_filters;
    let velocity = calib.settings.radar_velocity_compensation;
    let mut points = RadarPoints::new(cam);
    let mut sweeps: BTreeMap<String, usize> = BTreeMap::new();
    for (e, path) in chosen_entries(calibration, &calib, radar_files)? {
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
        name: jpeg
            .file_stem()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
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

/// Predict a depth map (metres, the input's frame size).
pub fn predict(
    net: &DepthNet,
    input: &PredictInput,
    radar: Option<RadarInput>,
    device: Device,
) -> Result<DepthMap, NetError> {
    depthsense_model::device::autotune_fixed_size(device);
    let (w, h) = input.image.dimensions();
    let img = Tensor::from_slice(&normalise_image(&input.image, &Augment::NONE))
        .view([1, 3, h as i64, w as i64])
        .to_device(device);
    let mer_channels;
    let planes: Vec<&[f32]> = match radar {
        None => vec![],
        Some(RadarInput::Height) => vec![&input.radar_height.depth_m],
        Some(RadarInput::Raw) => vec![&input.radar_raw.depth_m],
        Some(RadarInput::RawHeight) => {
            vec![&input.radar_raw.depth_m, &input.radar_height.depth_m]
        }
        Some(RadarInput::Mer) => {
            let (d, c) = input.mer.as_ref().ok_or_else(|| {
                NetError::Config(format!(
                    "{}: the model takes MER radar (SPEC §5) but the input has no MER maps: \
                     run `depthsense mer apply` on the prepared data or pass --mer-checkpoint",
                    input.name
                ))
            })?;
            mer_channels = depthsense_dataset::mer_maps::derive_channels(&d.depth_m, &c.depth_m);
            let n = d.depth_m.len();
            let mut v: Vec<&[f32]> = vec![&input.radar_raw.depth_m];
            v.extend(mer_channels.chunks(n));
            v
        }
    };
    let radar_t = if planes.is_empty() {
        Tensor::zeros([1, 1, h as i64, w as i64], (Kind::Float, device))
    } else {
        let flat: Vec<f32> = planes.concat();
        Tensor::from_slice(&flat)
            .view([1, planes.len() as i64, h as i64, w as i64])
            .to_device(device)
    };
    let pred = tch::no_grad(|| net.decode(&net.forward_t(&img, &radar_t, false)));
    let pred = pred
        .to_device(Device::Cpu)
        .to_kind(Kind::Float)
        .contiguous();
    if pred.numel() != (w * h) as usize {
        return Err(NetError::Other(format!(
            "prediction has shape {:?}, expected [1, 1, {h}, {w}]",
            pred.size()
        )));
    }
    Ok(DepthMap {
        width: w,
        height: h,
        depth_m: Vec::<f32>::try_from(pred.view([-1]))?,
    })
}

/// The files [`write_outputs`] writes.
pub const OUTPUT_FILES: [&str; 4] = [
    "depth.png",
    "depth_color.png",
    "radar_overlay.png",
    "image.png",
];

/// Write depth.png, depth_color.png, radar_overlay.png and image.png into `out`.
pub fn write_outputs(
    out: &Path,
    input: &PredictInput,
    depth: &DepthMap,
    max_m: f32,
) -> Result<Vec<PathBuf>, NetError> {
    std::fs::create_dir_all(out).map_err(|e| NetError::io(out, e))?;
    let mut written = vec![];
    let mut w = |name: &str, bytes: Vec<u8>| -> Result<(), NetError> {
        let p = out.join(name);
        write_atomic(&p, &bytes).map_err(|e| NetError::io(&p, e))?;
        written.push(p);
        Ok(())
    };
    w("depth.png", encode_png(depth)?)?;
    let color =
        depthsense_viz::plot::colorize_depth(&depth.depth_m, depth.width, depth.height, max_m);
    w("depth_color.png", depthsense_viz::plot::encode_rgb(&color)?)?;
    let overlay =
        depthsense_viz::plot::overlay_points(&input.image, &input.radar_raw.depth_m, max_m, 3);
    w(
        "radar_overlay.png",
        depthsense_viz::plot::encode_rgb(&overlay)?,
    )?;
    w("image.png", depthsense_viz::plot::encode_rgb(&input.image)?)?;
    Ok(written)
}

/// Computes the MER maps of a `predict` input with a PDA network (`predict --mer-checkpoint`:
/// sample tokens and raw files carry no MER maps of their own).
pub fn attach_mer(
    input: &mut PredictInput,
    net: &depthsense_model::pda::PdaNet,
    device: Device,
) -> Result<(), NetError> {
    input.mer = Some(depthsense_mer::apply::mer_maps_for_image(
        &input.image,
        &input.radar_raw,
        net,
        device,
    )?);
    Ok(())
}
