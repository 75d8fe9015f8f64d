//! The `prepare` pipeline: raw nuScenes keyframes → training-frame maps on disk
//! (layout in [`crate::layout`]).

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use depthsense_nuscenes::depth_png::{encode_png_fast, DepthMap};
use depthsense_nuscenes::geometry::{
    apply_f32, cam_from_sensor, ego_from_sensor, global_from_ego, rotation_from_wxyz, Camera, Rigid,
};
use depthsense_nuscenes::pcd::{read_lidar_pcd_bin, read_radar_pcd};
use depthsense_nuscenes::tables::{NuScenes, Sample, SampleAnnotation, SampleData, Token};
use depthsense_nuscenes::NuError;
use rayon::prelude::*;

use crate::layout::{self, conditions_of, IndexEntry, PreparedIndex, SampleMeta};
use crate::maps::{self, Raster};
use crate::motion::{self, BoxAt, TrackPoint};
use crate::radar_points::{RadarPoints, RADAR_POINTS_FILE};

pub use crate::splits::split_scene_tokens;

/// Options of `depthsense prepare`.
#[derive(Debug, Clone, PartialEq)]
pub struct PrepareOptions {
    pub dataroot: PathBuf,
    /// Version folder name, e.g. "v1.0-mini", "v1.0-trainval", "v1.0-synth".
    pub version: String,
    pub out: PathBuf,
    /// Split name (see `splits::SPLIT_NAMES`); "all" = every scene of the version.
    pub split: String,
    /// Radar sweeps per channel: the keyframe sweep and N−1 previous ones (SPEC §2).
    pub radar_sweeps: usize,
    pub radar_channels: Vec<String>,
    /// K: the dense lidar target accumulates keyframe ±K sweeps (SPEC §4).
    pub lidar_sweeps: usize,
    /// Devkit default radar filters (SPEC §2).
    pub radar_filters: bool,
    /// Radar velocity compensation (vx_comp, vy_comp × Δt) for multi-sweep radar.
    pub radar_velocity_compensation: bool,
    /// Worker threads; 0 = all cores.
    pub jobs: usize,
    /// Exit status 0 even when some samples failed.
    pub keep_going: bool,
    /// `--shard I/N`: prepare only the I-th of N disjoint parts (by scene) of the selection;
    /// its index goes to `index.shard-I-of-N.json` (merge with `depthsense index merge`).
    pub shard: Option<Shard>,
    /// `--verify`: re-read every sample already in `out` ([`crate::verify`]) and prepare the
    /// broken ones again.
    pub verify: bool,
}

/// One part of a sharded `prepare` (`--shard I/N`, 0 ≤ I < N).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl std::str::FromStr for Shard {
    type Err = PrepError;
    /// "I/N" with 0 ≤ I < N (Slurm: `--shard $SLURM_ARRAY_TASK_ID/16`).
    fn from_str(s: &str) -> Result<Shard, PrepError> {
        let bad = |fault| PrepError::BadShard {
            value: s.to_string(),
            fault,
        };
        let (i, n) = s.split_once('/').ok_or_else(|| bad(ShardFault::NoSlash))?;
        let index: usize = i
            .trim()
            .parse()
            .map_err(|_| bad(ShardFault::IndexNotANumber))?;
        let count: usize = n
            .trim()
            .parse()
            .map_err(|_| bad(ShardFault::CountNotANumber))?;
        if count == 0 || index >= count {
            return Err(bad(ShardFault::OutOfRange));
        }
        Ok(Shard { index, count })
    }
}

impl Default for PrepareOptions {
    fn default() -> Self {
        Self {
            dataroot: PathBuf::from("data/nuscenes"),
            version: "v1.0-mini".into(),
            out: PathBuf::from("data/prepared"),
            split: "all".into(),
            radar_sweeps: 5,
            radar_channels: vec![
                "RADAR_FRONT".into(),
                "RADAR_FRONT_LEFT".into(),
                "RADAR_FRONT_RIGHT".into(),
            ],
            lidar_sweeps: 0,
            radar_filters: true,
            radar_velocity_compensation: false,
            jobs: 0,
            keep_going: false,
            shard: None,
            verify: false,
        }
    }
}

/// What a `prepare` run did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PrepareSummary {
    pub prepared: usize,
    pub skipped_existing: usize,
    /// (sample token, reason) of every sample that could not be prepared.
    pub failed: Vec<(String, String)>,
    /// `--verify`: samples already there that were checked, and (token, what was wrong) of
    /// those found broken and prepared again.
    pub verified: usize,
    pub rebuilt: Vec<(String, String)>,
    /// Of the rebuilt samples, how many had MER maps (`mer apply` must run again for them).
    pub mer_lost: usize,
}

pub use crate::error::{PrepError, ShardFault};

pub use crate::motion::{BOX_MARGIN_M, MAX_TIME_DIFF_S, MOVING_SPEED_MPS};

/// Version of the dense-target rules, stored with the settings: a prepared folder made under
/// other rules is not mixed with this run's samples. `keyframe-surface-1`: near-sensor points
/// removed from every sweep (devkit `remove_close(1.0)`), other sweeps judged against the
/// keyframe surface (keyframe pixels always kept), moving boxes interpolated to each sweep's
/// time with a 0.2 m margin. `keyframe-surface-2`: the same, and the ego car's body box
/// ([`maps::EGO_BOX`], in each sweep's ego frame) removed from the other sweeps too.
pub const DENSE_RULES: &str = "keyframe-surface-2";

/// Time spent per stage, summed over samples (seconds).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct StageTimes {
    pub decode_s: f64,
    pub project_s: f64,
    pub encode_s: f64,
    pub write_s: f64,
}

/// The maps of one sample, in memory.
pub struct SampleMaps {
    pub meta: SampleMeta,
    /// 800x350 RGB8.
    pub image_rgb: Vec<u8>,
    pub lidar_sparse: DepthMap,
    pub lidar_dense: DepthMap,
    pub lowheight_mask: Vec<u8>,
    pub radar_raw: DepthMap,
    pub radar_height: DepthMap,
    /// The radar returns behind the radar maps (SPEC §10.7/§10.8 re-rasterisation).
    pub radar_points: RadarPoints,
}

/// Everything a worker needs besides the tables.
struct Job<'a> {
    nu: &'a NuScenes,
    opts: &'a PrepareOptions,
    times: &'a Mutex<StageTimes>,
}

/// Compute all maps of one sample (no writing).
pub fn compute_sample(
    nu: &NuScenes,
    sample: &Sample,
    opts: &PrepareOptions,
) -> Result<SampleMaps, PrepError> {
    let times = Mutex::new(StageTimes::default());
    compute(
        &Job {
            nu,
            opts,
            times: &times,
        },
        sample,
    )
}

/// Time spent in one sample, added to the run's [`StageTimes`] when the sample is done.
#[derive(Debug, Default)]
struct Clock {
    decode_s: f64,
    project_s: f64,
}

impl Clock {
    fn decode<T>(&mut self, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let r = f();
        self.decode_s += t.elapsed().as_secs_f64();
        r
    }
    fn project<T>(&mut self, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let r = f();
        self.project_s += t.elapsed().as_secs_f64();
        r
    }
}

/// The keyframe's camera and lidar records and the full-resolution camera model.
pub(crate) struct KeyframeSensors<'a> {
    pub(crate) cam_sd: &'a SampleData,
    pub(crate) lidar_sd: &'a SampleData,
    pub(crate) cam: Camera,
}

pub(crate) fn keyframe_sensors<'a>(
    nu: &'a NuScenes,
    sample: &Sample,
) -> Result<KeyframeSensors<'a>, PrepError> {
    let missing = |channel: &str| {
        PrepError::Nu(NuError::BadRecord {
            table: "sample",
            token: sample.token.to_string(),
            reason: format!("has no {channel} keyframe in sample_data"),
        })
    };
    let cam_sd = nu
        .keyframe(sample.token, "CAM_FRONT")
        .ok_or_else(|| missing("CAM_FRONT"))?;
    let lidar_sd = nu
        .keyframe(sample.token, "LIDAR_TOP")
        .ok_or_else(|| missing("LIDAR_TOP"))?;
    let cam_cs = nu.get_calibrated_sensor(
        cam_sd.calibrated_sensor_token,
        "sample_data",
        cam_sd.token,
        "calibrated_sensor_token",
    )?;
    let k = cam_cs.camera_intrinsic.ok_or_else(|| {
        PrepError::Nu(NuError::BadRecord {
            table: "calibrated_sensor",
            token: cam_cs.token.to_string(),
            reason: "CAM_FRONT calibration has no 3x3 camera_intrinsic".into(),
        })
    })?;
    let (w, h) = if cam_sd.width > 0 {
        (cam_sd.width, cam_sd.height)
    } else {
        (1600, 900)
    };
    Ok(KeyframeSensors {
        cam_sd,
        lidar_sd,
        cam: Camera::from_intrinsic(&k, w, h),
    })
}

/// CAM_FRONT JPEG → 800x350 RGB8 training frame (SPEC §3).
fn frame_image(
    nu: &NuScenes,
    cam_sd: &SampleData,
    clock: &mut Clock,
) -> Result<Vec<u8>, PrepError> {
    clock.decode(|| {
        let img_path = nu.path_of(cam_sd);
        reading(&img_path);
        let jpeg = std::fs::read(&img_path).map_err(|e| PrepError::io(&img_path, e))?;
        let bad_image = |reason: String| {
            PrepError::Nu(NuError::Image {
                path: img_path.display().to_string(),
                reason,
            })
        };
        let rgb = image::load_from_memory(&jpeg)
            .map_err(|e| bad_image(e.to_string()))?
            .into_rgb8();
        let (iw, ih) = rgb.dimensions();
        maps::image_to_frame(rgb.as_raw(), iw, ih)
            .ok_or_else(|| bad_image(format!("expected a 1600x900 image, found {iw}x{ih}")))
    })
}

/// Sparse GT and low-height mask from the keyframe sweep.
struct KeyframeLidar {
    sparse: Raster,
    lowheight_mask: Vec<u8>,
    cam_from_lidar: Rigid,
    nan_dropped: u64,
}

/// Sparse lidar GT and low-height mask: keyframe sweep only (SPEC §4).
fn keyframe_lidar(
    nu: &NuScenes,
    ks: &KeyframeSensors,
    counts: &mut BTreeMap<String, u64>,
    clock: &mut Clock,
) -> Result<KeyframeLidar, PrepError> {
    let lidar_path = nu.path_of(ks.lidar_sd);
    reading(&lidar_path);
    let scan = clock.decode(|| read_lidar_pcd_bin(&lidar_path))?;
    let t = Instant::now();
    // The ego car's own returns never reach the camera's frame from the keyframe pose, but they
    // go here too, as from every sweep (devkit remove_close).
    let (points_sensor, near_removed) = maps::remove_close(&scan.points, maps::NEAR_SENSOR_M);
    let cam_from_lidar = cam_from_sensor(nu, ks.lidar_sd, ks.cam_sd)?;
    let ego_from_lidar = ego_from_sensor(nu, ks.lidar_sd)?.to_f32();
    let heights_m: Vec<f32> = points_sensor
        .iter()
        .map(|p| apply_f32(&ego_from_lidar, *p)[2])
        .collect();
    let sparse = maps::project_points(&points_sensor, &cam_from_lidar, &ks.cam, |i| heights_m[i]);
    let lowheight_mask = maps::lowheight_mask(&sparse);
    counts.insert("lidar_points".into(), scan.points.len() as u64);
    counts.insert("lidar_near_sensor_removed".into(), near_removed);
    counts.insert("lidar_in_image".into(), sparse.in_frame);
    counts.insert("lidar_sparse_pixels".into(), sparse.valid());
    counts.insert(
        "lowheight_pixels".into(),
        lowheight_mask.iter().filter(|v| **v > 0).count() as u64,
    );
    clock.project_s += t.elapsed().as_secs_f64();
    Ok(KeyframeLidar {
        sparse,
        lowheight_mask,
        cam_from_lidar,
        nan_dropped: scan.nan_dropped as u64,
    })
}

/// One annotation as a [`TrackPoint`] (`None` for a rotation that is not a unit quaternion:
/// such a box is not used).
fn track_point(nu: &NuScenes, a: &SampleAnnotation, timestamp_us: i64) -> Option<TrackPoint> {
    rotation_from_wxyz(a.rotation, "sample_annotation").ok()?;
    let at = |t: Token| -> Option<(i64, [f64; 3])> {
        let b = nu.annotation(t)?;
        let s = nu
            .get_sample(b.sample_token, "sample_annotation", b.token, "sample_token")
            .ok()?;
        Some((s.timestamp_us, b.translation))
    };
    let velocity_mps = motion::devkit_velocity(
        a.prev.and_then(at),
        (timestamp_us, a.translation),
        a.next.and_then(at),
    );
    let speed_mps = velocity_mps
        .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
        .unwrap_or(0.0);
    let attr_moving = a.attribute_tokens.iter().any(|t| {
        nu.get_attribute(*t, "sample_annotation", a.token, "attribute_tokens")
            .map(|at| at.name.ends_with(".moving") || at.name == "cycle.with_rider")
            .unwrap_or(false)
    });
    Some(TrackPoint {
        timestamp_us,
        center_m: a.translation,
        rotation_wxyz: a.rotation,
        size_wlh_m: a.size,
        velocity_mps,
        moving: speed_mps > MOVING_SPEED_MPS || attr_moving,
    })
}

/// Annotation tracks (sorted by time, instance order) of the scene's instances that move at
/// some annotation within [`MAX_TIME_DIFF_S`] of `t_lo_us..=t_hi_us`; empty without
/// annotations. See [`crate::motion`] for the rule.
fn moving_tracks(
    nu: &NuScenes,
    sample: &Sample,
    t_lo_us: i64,
    t_hi_us: i64,
) -> Vec<Vec<TrackPoint>> {
    if nu.sample_annotation.is_none() {
        return Vec::new();
    }
    let reach_us = (MAX_TIME_DIFF_S * 1e6) as i64;
    let mut by_instance: BTreeMap<String, Vec<TrackPoint>> = BTreeMap::new();
    for s in nu
        .scene_samples(sample.scene_token)
        .into_iter()
        .filter(|s| s.timestamp_us >= t_lo_us - reach_us && s.timestamp_us <= t_hi_us + reach_us)
    {
        for a in nu.sample_annotations(s.token) {
            if let Some(p) = track_point(nu, a, s.timestamp_us) {
                by_instance
                    .entry(a.instance_token.to_string())
                    .or_default()
                    .push(p);
            }
        }
    }
    by_instance
        .into_values()
        .filter(|t| t.iter().any(|p| p.moving))
        .map(|mut t| {
            t.sort_by_key(|p| p.timestamp_us);
            t
        })
        .collect()
}

/// Dense target (SPEC §4, docs/guide/prepare.md, "The dense target"): the keyframe's own pixels, plus the points
/// of ±K sweeps moved through their own ego poses that survive, in this order,
/// 1. near-sensor removal (the ego car's own returns, devkit `remove_close(1.0)`), then the
///    ego car's body box in each sweep's ego frame ([`maps::EGO_BOX`]),
/// 2. moving boxes interpolated to the sweep's time ([`crate::motion`]),
/// 3. the keyframe-surface test ([`maps::KeyframeSurface`]): hidden and free-space points go.
///
/// A keyframe pixel is never removed or overwritten; among the other sweeps the nearest wins.
fn dense_lidar(
    nu: &NuScenes,
    sample: &Sample,
    ks: &KeyframeSensors,
    keyframe: &Raster,
    k: usize,
    counts: &mut BTreeMap<String, u64>,
    clock: &mut Clock,
) -> Result<(Raster, u64), PrepError> {
    let mut dense = Raster {
        depth_m: keyframe.depth_m.clone(),
        payload: vec![0.0; keyframe.payload.len()],
        in_frame: keyframe.in_frame,
    };
    let mut tally = DenseTally {
        sweeps_used: 1,
        ..Default::default()
    };
    if k > 0 {
        let others = other_lidar_sweeps(nu, ks.lidar_sd, k);
        let surface = clock.project(|| maps::KeyframeSurface::new(&keyframe.depth_m));
        let t_lo = others.iter().map(|s| s.timestamp_us).min();
        let t_hi = others.iter().map(|s| s.timestamp_us).max();
        let tracks = match (t_lo, t_hi) {
            (Some(lo), Some(hi)) => moving_tracks(nu, sample, lo, hi),
            _ => Vec::new(),
        };
        let cam_from_global = global_from_ego(nu, ks.cam_sd)?
            .compose(&ego_from_sensor(nu, ks.cam_sd)?)
            .inverse();
        let frame = DenseFrame {
            nu,
            ks,
            keyframe,
            surface: &surface,
            tracks: &tracks,
            cam_from_global: &cam_from_global,
        };
        for sw in others {
            add_dense_sweep(&frame, sw, &mut dense, &mut tally, clock)?;
        }
    }
    record_dense_counts(counts, &tally, &dense);
    Ok((dense, tally.nan_dropped))
}

/// The ±K lidar sweeps around the keyframe sweep (K back, then K forward; the keyframe's
/// own sweep excluded).
fn other_lidar_sweeps<'a>(
    nu: &'a NuScenes,
    lidar_sd: &'a SampleData,
    k: usize,
) -> Vec<&'a SampleData> {
    let mut others: Vec<&SampleData> = nu
        .sweeps_back(lidar_sd, k + 1)
        .into_iter()
        .skip(1)
        .collect();
    others.extend(nu.sweeps_forward(lidar_sd, k + 1).into_iter().skip(1));
    others
}

/// What every other sweep of the dense target is judged against.
struct DenseFrame<'a> {
    nu: &'a NuScenes,
    ks: &'a KeyframeSensors<'a>,
    keyframe: &'a Raster,
    surface: &'a maps::KeyframeSurface,
    /// Tracks of the moving instances ([`moving_tracks`]).
    tracks: &'a [Vec<TrackPoint>],
    cam_from_global: &'a Rigid,
}

/// Running totals over the dense target's sweeps (its `meta.json` counts).
#[derive(Debug, Default)]
struct DenseTally {
    nan_dropped: u64,
    near_removed: u64,
    ego_body_removed: u64,
    moving_removed: u64,
    judged: maps::SweepCounts,
    sweeps_used: u64,
}

/// Read one other sweep, filter it (near sensor, ego body, moving boxes) and add what survives
/// the keyframe-surface test to `dense`.
fn add_dense_sweep(
    f: &DenseFrame,
    sw: &SampleData,
    dense: &mut Raster,
    tally: &mut DenseTally,
    clock: &mut Clock,
) -> Result<(), PrepError> {
    let p = f.nu.path_of(sw);
    reading(&p);
    let s = clock.decode(|| read_lidar_pcd_bin(&p))?;
    let t = Instant::now();
    tally.nan_dropped += s.nan_dropped as u64;
    let (points_sensor, near) = maps::remove_close(&s.points, maps::NEAR_SENSOR_M);
    tally.near_removed += near;
    let points_global = sweep_points_global(f, sw, &points_sensor, tally)?;
    let c = maps::add_sweep_points(
        dense,
        &f.keyframe.depth_m,
        f.surface,
        &points_global,
        f.cam_from_global,
        &f.ks.cam,
    );
    tally.judged.in_frame += c.in_frame;
    tally.judged.on_keyframe_pixel += c.on_keyframe_pixel;
    tally.judged.hidden += c.hidden;
    tally.judged.free_space += c.free_space;
    tally.judged.kept += c.kept;
    tally.sweeps_used += 1;
    clock.project_s += t.elapsed().as_secs_f64();
    Ok(())
}

/// A sweep's points (near-sensor returns already gone) in the global frame, less those inside
/// the ego car's body box (in the sweep's ego frame) or a moving box at the sweep's time.
fn sweep_points_global(
    f: &DenseFrame,
    sw: &SampleData,
    points_sensor: &[[f32; 3]],
    tally: &mut DenseTally,
) -> Result<Vec<[f32; 3]>, PrepError> {
    let ego_from_lidar = ego_from_sensor(f.nu, sw)?;
    let global_from_sensor = global_from_ego(f.nu, sw)?.compose(&ego_from_lidar);
    let e = ego_from_lidar.to_f32();
    let g = global_from_sensor.to_f32();
    let boxes: Vec<BoxAt> = f
        .tracks
        .iter()
        .filter_map(|tr| motion::box_at(tr, sw.timestamp_us, BOX_MARGIN_M))
        .collect();
    let mut points_global: Vec<[f32; 3]> = Vec::with_capacity(points_sensor.len());
    for q in points_sensor {
        let p_ego = apply_f32(&e, *q);
        if maps::EGO_BOX.contains(p_ego) {
            tally.ego_body_removed += 1;
            continue;
        }
        let pg = apply_f32(&g, *q);
        if boxes.iter().any(|b| b.contains(pg)) {
            tally.moving_removed += 1;
        } else {
            points_global.push(pg);
        }
    }
    Ok(points_global)
}

/// The dense target's counts in `meta.json`.
fn record_dense_counts(counts: &mut BTreeMap<String, u64>, tally: &DenseTally, dense: &Raster) {
    counts.insert("lidar_dense_sweeps".into(), tally.sweeps_used);
    counts.insert("lidar_dense_pixels".into(), dense.valid());
    counts.insert("lidar_dense_near_sensor_removed".into(), tally.near_removed);
    counts.insert(
        "lidar_dense_ego_body_removed".into(),
        tally.ego_body_removed,
    );
    counts.insert("lidar_dense_occluded_removed".into(), tally.judged.hidden);
    counts.insert(
        "lidar_dense_free_space_removed".into(),
        tally.judged.free_space,
    );
    counts.insert(
        "lidar_dense_on_keyframe_pixel".into(),
        tally.judged.on_keyframe_pixel,
    );
    counts.insert("lidar_moving_removed".into(), tally.moving_removed);
}

/// Radar inputs of one sample.
struct RadarInputs {
    raw: Raster,
    height: Raster,
    /// The returns behind `raw` and `height` (written as `radar_points.bin`).
    points: RadarPoints,
    cam_from_radar: BTreeMap<String, [[f64; 4]; 4]>,
    /// Requested channels without a keyframe in this sample.
    missing: Vec<String>,
    nan_dropped: u64,
    /// Returns read that passed the filters (count `radar_points`).
    points_read: u64,
    /// Returns the filters removed (count `radar_filtered_out`).
    filtered_out: u64,
}

/// Radar (SPEC §5): N sweeps of each chosen channel.
fn radar_inputs(
    nu: &NuScenes,
    sample: &Sample,
    ks: &KeyframeSensors,
    opts: &PrepareOptions,
    sd_tokens: &mut BTreeMap<String, String>,
    counts: &mut BTreeMap<String, u64>,
    clock: &mut Clock,
) -> Result<RadarInputs, PrepError> {
    let mut out = RadarInputs {
        raw: Raster::default(),
        height: Raster::default(),
        points: RadarPoints::new(ks.cam),
        cam_from_radar: BTreeMap::new(),
        missing: Vec::new(),
        nan_dropped: 0,
        points_read: 0,
        filtered_out: 0,
    };
    let frame = RadarFrame { nu, ks, opts };
    for ch in &opts.radar_channels {
        let Some(kf) = nu.keyframe(sample.token, ch) else {
            out.missing.push(ch.clone());
            continue;
        };
        sd_tokens.insert(ch.clone(), kf.token.to_string());
        for (si, sw) in nu
            .sweeps_back(kf, opts.radar_sweeps.max(1))
            .into_iter()
            .enumerate()
        {
            add_radar_sweep(&frame, ch, si, sw, &mut out, clock)?;
        }
    }
    // One rasterisation for every channel and sweep: the same function re-rasterises the
    // stored points (perturbation, partial radar drop), so the maps are reproducible.
    let t = Instant::now();
    let maps = out.points.rasterise();
    (out.raw, out.height) = (maps.raw, maps.height);
    clock.project_s += t.elapsed().as_secs_f64();
    counts.insert("radar_points".into(), out.points_read);
    counts.insert("radar_in_image".into(), out.raw.in_frame);
    counts.insert("radar_raw_pixels".into(), out.raw.valid());
    counts.insert("radar_height_pixels".into(), out.height.valid());
    counts.insert("radar_filtered_out".into(), out.filtered_out);
    Ok(out)
}

/// What every radar sweep of a sample is moved into the camera frame with.
struct RadarFrame<'a> {
    nu: &'a NuScenes,
    ks: &'a KeyframeSensors<'a>,
    opts: &'a PrepareOptions,
}

/// Read sweep `si` (0 = the keyframe sweep) of radar channel `ch`, filter it, and add its
/// returns in the camera frame to `out.points` (the keyframe sweep's calibration goes to
/// `out.cam_from_radar`).
fn add_radar_sweep(
    f: &RadarFrame,
    ch: &str,
    si: usize,
    sw: &SampleData,
    out: &mut RadarInputs,
    clock: &mut Clock,
) -> Result<(), PrepError> {
    let (nu, ks, opts) = (f.nu, f.ks, f.opts);
    let p = nu.path_of(sw);
    reading(&p);
    let scan = clock.decode(|| read_radar_pcd(&p))?;
    let t = Instant::now();
    out.nan_dropped += scan.nan_dropped as u64;
    let dt = opts
        .radar_velocity_compensation
        .then(|| velocity_dt_s(ks.cam_sd.timestamp_us, sw.timestamp_us));
    let tf = cam_from_sensor(nu, sw, ks.cam_sd)?;
    if si == 0 {
        out.cam_from_radar.insert(ch.to_string(), tf.to_mat4());
    }
    let (kept, filtered_out) = add_sweep(
        &mut out.points,
        &RadarSweep {
            channel: ch,
            index: si,
            cam_from_radar: &tf,
            dt_s: dt,
        },
        &scan,
        opts.radar_filters,
    );
    out.filtered_out += filtered_out as u64;
    out.points_read += kept as u64;
    clock.project_s += t.elapsed().as_secs_f64();
    Ok(())
}

/// One radar sweep as [`add_sweep`] places it.
pub struct RadarSweep<'a> {
    /// `RADAR_FRONT`, …
    pub channel: &'a str,
    /// 0 = the keyframe sweep, 1 = the one before, …
    pub index: usize,
    /// The sweep's sensor into the keyframe camera (ego motion between the two included).
    pub cam_from_radar: &'a Rigid,
    /// Velocity compensation: the returns move by (vx_comp, vy_comp) × dt_s.
    pub dt_s: Option<f32>,
}

/// Adds the returns of `scan` (the devkit filters applied when `filters`) to `points` in the
/// camera frame, as `prepare` does for every sweep; returns (kept, filtered out). `predict
/// --image` builds its radar through the same function, so that it feeds a model what
/// training fed it.
pub fn add_sweep(
    points: &mut RadarPoints,
    sweep: &RadarSweep,
    scan: &depthsense_nuscenes::pcd::RadarScan,
    filters: bool,
) -> (usize, usize) {
    let (pts, filtered_out) = scan.filtered(filters);
    let pos = maps::radar_positions(&pts, sweep.dt_s);
    let m = sweep.cam_from_radar.to_f32();
    let points_cam: Vec<[f32; 3]> = pos.iter().map(|q| apply_f32(&m, *q)).collect();
    let origin_cam = sweep.cam_from_radar.t.map(|v| v as f32);
    points.push_sweep(sweep.channel, sweep.index, origin_cam, &points_cam);
    (pts.len(), filtered_out)
}

/// Seconds from a radar sweep to the camera frame it is drawn into (velocity compensation).
pub fn velocity_dt_s(camera_timestamp_us: i64, sweep_timestamp_us: i64) -> f32 {
    (camera_timestamp_us - sweep_timestamp_us) as f32 * 1e-6
}

/// The settings recorded in `meta.json`.
fn sample_settings(
    nu: &NuScenes,
    opts: &PrepareOptions,
    radar_missing: &[String],
) -> serde_json::Value {
    let annotations_present = nu.sample_annotation.is_some();
    serde_json::json!({
        "version": nu.version,
        "split": opts.split,
        "radar_sweeps": opts.radar_sweeps,
        "radar_channels": opts.radar_channels,
        "radar_channels_missing": radar_missing,
        "radar_filters": opts.radar_filters,
        "radar_velocity_compensation": opts.radar_velocity_compensation,
        "radar_h_up_m": maps::RADAR_H_UP_M,
        "radar_h_down_m": maps::RADAR_H_DOWN_M,
        "lidar_sweeps_k": opts.lidar_sweeps,
        "dense_rules": DENSE_RULES,
        "near_sensor_removal": format!("every sweep: devkit remove_close({}), |x| < {0} m and |y| < {0} m in the sensor frame", maps::NEAR_SENSOR_M),
        "ego_body_removal": format!("non-keyframe sweeps: points of the ego box {} < x < {} m, |y| < {} m, z < {} m in the sweep's ego frame", maps::EGO_BOX.x_min_m, maps::EGO_BOX.x_max_m, maps::EGO_BOX.y_half_m, maps::EGO_BOX.z_max_m),
        "occlusion_filter": {"against": "keyframe surface (keyframe pixels always kept)", "rx": maps::OCC_RX, "max_gap_rows": maps::OCC_MAX_GAP_ROWS, "rel": maps::OCC_REL, "abs_m": maps::OCC_ABS_M},
        "moving_objects": if annotations_present {
            format!("removed from non-keyframe sweeps: boxes of instances moving faster than {MOVING_SPEED_MPS} m/s or with a moving attribute, interpolated to the sweep time (linear centre, slerp rotation, max_time_diff {MAX_TIME_DIFF_S} s), +{BOX_MARGIN_M} m margin")
        } else {
            "not removed: this version has no sample_annotation table".to_string()
        },
        "annotations_present": annotations_present,
        "lowheight_band_m": [maps::LOW_HEIGHT_MIN_M, maps::LOW_HEIGHT_MAX_M],
    })
}

/// Compute all maps of one sample and add its stage times to the run's.
fn compute(job: &Job, sample: &Sample) -> Result<SampleMaps, PrepError> {
    let mut clock = Clock::default();
    let ks = keyframe_sensors(job.nu, sample)?;
    let measured = measure(job, sample, &ks, &mut clock)?;
    let maps = assemble(job.nu, job.opts, sample, &ks, measured)?;
    if let Ok(mut tm) = job.times.lock() {
        tm.decode_s += clock.decode_s;
        tm.project_s += clock.project_s;
    }
    Ok(maps)
}

/// Unit tests: panic in a sample listed in [`PANIC_ON`].
#[cfg(test)]
fn inject_test_panic(sample: &Sample) {
    if PANIC_ON
        .lock()
        .map(|v| v.contains(&sample.token.to_string()))
        .unwrap_or(false)
    {
        panic!("injected test panic");
    }
}

/// Outside unit tests no sample panics on purpose.
#[cfg(not(test))]
fn inject_test_panic(_sample: &Sample) {}

/// Everything read and projected for one sample, before `meta.json` is put together.
struct Measured {
    image_rgb: Vec<u8>,
    keyframe: KeyframeLidar,
    dense: Raster,
    radar: RadarInputs,
    sd_tokens: BTreeMap<String, String>,
    counts: BTreeMap<String, u64>,
}

/// Read and project the inputs of one sample: image, keyframe lidar, dense target, radar.
fn measure(
    job: &Job,
    sample: &Sample,
    ks: &KeyframeSensors,
    clock: &mut Clock,
) -> Result<Measured, PrepError> {
    let nu = job.nu;
    let opts = job.opts;
    let mut counts: BTreeMap<String, u64> = BTreeMap::new();
    let image_rgb = frame_image(nu, ks.cam_sd, clock)?;
    let kl = keyframe_lidar(nu, ks, &mut counts, clock)?;
    inject_test_panic(sample);
    let (dense, dense_nan) = dense_lidar(
        nu,
        sample,
        ks,
        &kl.sparse,
        opts.lidar_sweeps,
        &mut counts,
        clock,
    )?;
    let mut sd_tokens = BTreeMap::new();
    sd_tokens.insert("CAM_FRONT".to_string(), ks.cam_sd.token.to_string());
    sd_tokens.insert("LIDAR_TOP".to_string(), ks.lidar_sd.token.to_string());
    let radar = radar_inputs(nu, sample, ks, opts, &mut sd_tokens, &mut counts, clock)?;
    counts.insert(
        "nan_dropped".into(),
        kl.nan_dropped + dense_nan + radar.nan_dropped,
    );
    Ok(Measured {
        image_rgb,
        keyframe: kl,
        dense,
        radar,
        sd_tokens,
        counts,
    })
}

/// `meta.json` and the maps of one measured sample.
fn assemble(
    nu: &NuScenes,
    opts: &PrepareOptions,
    sample: &Sample,
    ks: &KeyframeSensors,
    m: Measured,
) -> Result<SampleMaps, PrepError> {
    let scene = nu.get_scene(sample.scene_token, "sample", sample.token, "scene_token")?;
    let meta = SampleMeta {
        sample_token: sample.token.to_string(),
        scene_token: scene.token.to_string(),
        scene_name: scene.name.clone(),
        conditions: conditions_of(&scene.description),
        timestamp_us: sample.timestamp_us,
        sample_data_tokens: m.sd_tokens,
        intrinsics_frame: ks.cam.frame_intrinsics(),
        intrinsics_full: ks.cam.intrinsics(),
        cam_from_lidar: m.keyframe.cam_from_lidar.to_mat4(),
        cam_from_radar: m.radar.cam_from_radar,
        counts: m.counts,
        settings: sample_settings(nu, opts, &m.radar.missing),
    };
    Ok(SampleMaps {
        meta,
        image_rgb: m.image_rgb,
        lidar_sparse: m.keyframe.sparse.to_depth_map(),
        lidar_dense: m.dense.to_depth_map(),
        lowheight_mask: m.keyframe.lowheight_mask,
        radar_raw: m.radar.raw.to_depth_map(),
        radar_height: m.radar.height.to_depth_map(),
        radar_points: m.radar.points,
    })
}

fn encode_rgb_png(rgb: &[u8], w: u32, h: u32, gray: bool) -> Result<Vec<u8>, image::ImageError> {
    use image::ImageEncoder;
    let mut out = Vec::with_capacity(rgb.len() / 2);
    let enc = image::codecs::png::PngEncoder::new_with_quality(
        &mut out,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Adaptive,
    );
    let ct = if gray {
        image::ExtendedColorType::L8
    } else {
        image::ExtendedColorType::Rgb8
    };
    enc.write_image(rgb, w, h, ct)?;
    Ok(out)
}

/// Removes a temporary sample folder unless the sample was committed (also while unwinding
/// from a panic), so a failed sample leaves nothing behind.
struct TempDirGuard {
    path: PathBuf,
    committed: bool,
}

impl Drop for TempDirGuard {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}

/// Encode and write one sample atomically: files go to this process's temporary sibling
/// directory (`.tmp-<pid>-<token>`), `meta.json` last, then the directory is renamed into
/// place. When another process completed the same sample meanwhile, this copy is dropped.
fn write_sample(out: &Path, maps: &SampleMaps, times: &Mutex<StageTimes>) -> Result<(), PrepError> {
    let t = Instant::now();
    let files = encode_sample(maps)?;
    let encode_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let res = write_sample_dir(out, &maps.meta.sample_token, &files);
    if let Ok(mut tm) = times.lock() {
        tm.encode_s += encode_s;
        tm.write_s += t.elapsed().as_secs_f64();
    }
    res
}

/// The files of one sample folder (name, bytes), `meta.json` last.
fn encode_sample(maps: &SampleMaps) -> Result<Vec<(&'static str, Vec<u8>)>, PrepError> {
    let fw = layout::FRAME_W;
    let fh = layout::FRAME_H;
    // A file that cannot be encoded is named as it would be written: <sample token>/<file>.
    let token = &maps.meta.sample_token;
    let depth = |file: &'static str, m: &DepthMap| {
        let bytes =
            encode_png_fast(m).map_err(|e| PrepError::encode(format!("{token}/{file}"), e))?;
        Ok::<_, PrepError>((file, bytes))
    };
    let mask = |file: &'static str, m: &[u8], gray: bool| {
        let bytes = encode_rgb_png(m, fw, fh, gray)
            .map_err(|e| PrepError::encode(format!("{token}/{file}"), e))?;
        Ok::<_, PrepError>((file, bytes))
    };
    Ok(vec![
        mask(layout::IMAGE_FILE, &maps.image_rgb, false)?,
        depth(layout::LIDAR_SPARSE_FILE, &maps.lidar_sparse)?,
        depth(layout::LIDAR_DENSE_FILE, &maps.lidar_dense)?,
        mask(layout::LOWHEIGHT_MASK_FILE, &maps.lowheight_mask, true)?,
        depth(layout::RADAR_RAW_FILE, &maps.radar_raw)?,
        depth(layout::RADAR_HEIGHT_FILE, &maps.radar_height)?,
        (RADAR_POINTS_FILE, maps.radar_points.encode()),
        (
            layout::META_FILE,
            serde_json::to_vec_pretty(&maps.meta)
                .map_err(|e| PrepError::encode(format!("{token}/{}", layout::META_FILE), e))?,
        ),
    ])
}

/// Write `files` into the sample's temporary folder and rename it to `out/<sample_token>`;
/// the temporary folder is removed on every path but the rename.
fn write_sample_dir(
    out: &Path,
    sample_token: &str,
    files: &[(&str, Vec<u8>)],
) -> Result<(), PrepError> {
    let final_dir = out.join(sample_token);
    let mut guard = TempDirGuard {
        path: out.join(crate::index::temp_dir_name(sample_token)),
        committed: false,
    };
    let tmp = guard.path.clone();
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| PrepError::io(&tmp, e))?;
    }
    std::fs::create_dir_all(&tmp).map_err(|e| PrepError::io(&tmp, e))?;
    for (name, bytes) in files {
        let p = tmp.join(name);
        std::fs::write(&p, bytes).map_err(|e| PrepError::io(&p, e))?;
    }
    let complete = |d: &Path| d.join(layout::META_FILE).is_file();
    if complete(&final_dir) {
        // Another process finished this sample meanwhile (same settings, same bytes).
        return Ok(());
    }
    if final_dir.exists() {
        // An incomplete directory (no meta.json) from an older run.
        std::fs::remove_dir_all(&final_dir).map_err(|e| PrepError::io(&final_dir, e))?;
    }
    match std::fs::rename(&tmp, &final_dir) {
        Ok(()) => {
            guard.committed = true;
            Ok(())
        }
        // Lost a race with another process that renamed its copy first.
        Err(_) if complete(&final_dir) => Ok(()),
        Err(e) => Err(PrepError::io(&final_dir, e)),
    }
}

thread_local! {
    /// The input file this worker thread is reading, for the message of a panic.
    static CURRENT_INPUT: std::cell::RefCell<Option<PathBuf>> = const { std::cell::RefCell::new(None) };
}

/// Note the file being read (named in the failure when the sample panics).
fn reading(path: &Path) {
    CURRENT_INPUT.with(|c| *c.borrow_mut() = Some(path.to_path_buf()));
}

fn panic_text(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "(no message)".to_string()
    }
}

/// Unit tests: sample tokens whose preparation panics.
#[cfg(test)]
static PANIC_ON: Mutex<Vec<String>> = Mutex::new(Vec::new());

/// Compute and write one sample; a panic anywhere inside (a reader bug, an arithmetic
/// overflow, …) fails this sample only, with the file being read named, and leaves no output.
fn prepare_one(job: &Job, sample: &Sample) -> Result<(), PrepError> {
    CURRENT_INPUT.with(|c| *c.borrow_mut() = None);
    let run = std::panic::AssertUnwindSafe(|| {
        compute(job, sample).and_then(|m| write_sample(&job.opts.out, &m, job.times))
    });
    match std::panic::catch_unwind(run) {
        Ok(r) => r,
        Err(payload) => {
            let input = CURRENT_INPUT.with(|c| c.borrow_mut().take());
            Err(PrepError::Panicked {
                sample: sample.token.to_string(),
                input: input
                    .map(|p| p.display().to_string())
                    .unwrap_or_else(|| "(no input file open)".into()),
                reason: panic_text(payload.as_ref()),
            })
        }
    }
}

/// Samples of the chosen split in scene order (splits from [`crate::splits::assign_splits`]).
pub fn select_samples<'a>(nu: &'a NuScenes, split: &str) -> Result<Vec<&'a Sample>, PrepError> {
    let a = crate::splits::assign_splits(nu)?;
    select_samples_in(nu, split, &a)
}

/// Samples of split `split` under the assignment `a`, in scene order.
pub fn select_samples_in<'a>(
    nu: &'a NuScenes,
    split: &str,
    a: &crate::splits::SplitAssignment,
) -> Result<Vec<&'a Sample>, PrepError> {
    if !crate::splits::SPLIT_NAMES.contains(&split) {
        return Err(PrepError::UnknownSplit(split.to_string()));
    }
    let mut scenes: Vec<_> = nu.scene.iter().collect();
    scenes.retain(|s| a.contains(split, &s.token.to_string()));
    if scenes.is_empty() {
        return Err(PrepError::EmptySplit {
            split: split.to_string(),
            version: nu.version.clone(),
            scenes: nu.scene.len(),
        });
    }
    Ok(scenes
        .iter()
        .flat_map(|s| nu.scene_samples(s.token))
        .collect())
}

/// Prepare every keyframe of the chosen split (see the crate docs and `layout`).
/// Finished samples (with `meta.json`) are skipped; failed samples are listed in the summary.
pub fn prepare(
    opts: &PrepareOptions,
    progress: &depthsense_progress::Progress,
) -> Result<PrepareSummary, PrepError> {
    prepare_timed(opts, progress).map(|(s, _)| s)
}

/// [`prepare`] that also returns the time per stage (for `bench data`).
pub fn prepare_timed(
    opts: &PrepareOptions,
    progress: &depthsense_progress::Progress,
) -> Result<(PrepareSummary, StageTimes), PrepError> {
    progress.set_message(format!("loading {} tables", opts.version));
    let nu = NuScenes::load(&opts.dataroot, &opts.version)?;
    let assignment = crate::splits::assign_splits(&nu)?;
    let selected = select_samples_in(&nu, &opts.split, &assignment)?;
    let (samples, shard_info) = shard_selection(selected, opts.shard);
    progress.set_message(match opts.shard {
        Some(sh) => format!("{} split {} shard {sh}", opts.version, opts.split),
        None => format!("{} split {}", opts.version, opts.split),
    });
    let _writing = open_output(opts)?;
    let indexed = check_output_indexes(opts, &nu.version)?;
    let done = |s: &Sample| {
        opts.out
            .join(s.token.to_string())
            .join(layout::META_FILE)
            .is_file()
    };
    let (mut existing, mut todo): (Vec<&Sample>, Vec<&Sample>) =
        samples.iter().partition(|s| done(s));
    let verified = existing.len();
    let (rebuilt, mer_lost) = if opts.verify {
        verify_existing(opts, &mut existing, &mut todo, progress)?
    } else {
        (vec![], 0)
    };
    if !indexed {
        check_unindexed_settings(opts, &existing)?;
    }
    progress.set_length(todo.len() as u64);
    progress.println(plan_line(opts, todo.len(), existing.len()));
    let times = Mutex::new(StageTimes::default());
    let job = Job {
        nu: &nu,
        opts,
        times: &times,
    };
    let results = prepare_all(&job, &todo, progress)?;
    let (mut summary, ok) = summarise(&existing, results);
    if opts.verify {
        summary.verified = verified;
        summary.rebuilt = rebuilt;
        summary.mer_lost = mer_lost;
    }
    write_index(&nu, opts, &samples, &ok, &assignment, shard_info)?;
    let t = times.into_inner().unwrap_or_default();
    Ok((summary, t))
}

/// A folder from before settings lived in the index: its settings are compared with those of
/// a finished sample (the first of `existing`, when there is one).
fn check_unindexed_settings(opts: &PrepareOptions, existing: &[&Sample]) -> Result<(), PrepError> {
    if let Some(s) = existing.first() {
        check_settings(
            &opts.out.join(s.token.to_string()).join(layout::META_FILE),
            opts,
        )?;
    }
    Ok(())
}

/// The line `prepare` starts with: how many keyframes it prepares (`todo`) and found done
/// (`done`), from where and into where.
fn plan_line(opts: &PrepareOptions, todo: usize, done: usize) -> String {
    format!(
        "{} keyframes to prepare ({} already done) from {} ({}, split {}{}) into {}",
        todo,
        done,
        opts.dataroot.display(),
        opts.version,
        opts.split,
        opts.shard
            .map_or(String::new(), |sh| format!(", shard {sh}")),
        opts.out.display()
    )
}

/// `--verify`: re-reads every sample of `existing` (on all cores); each broken one is removed
/// from `out`, moved to `todo` and returned with what was wrong, with how many of them had MER
/// maps.
fn verify_existing<'a>(
    opts: &PrepareOptions,
    existing: &mut Vec<&'a Sample>,
    todo: &mut Vec<&'a Sample>,
    progress: &depthsense_progress::Progress,
) -> Result<(Vec<(String, String)>, usize), PrepError> {
    progress.set_message(format!("verifying {} samples", existing.len()));
    let dir = |s: &Sample| opts.out.join(s.token.to_string());
    let problems: Vec<Option<String>> = existing
        .par_iter()
        .map(|s| crate::verify::verify_sample(&dir(s)).err())
        .collect();
    let (mut rebuilt, mut mer_lost, mut keep) = (vec![], 0, vec![]);
    for (s, problem) in existing.iter().zip(problems) {
        match problem {
            None => keep.push(*s),
            Some(why) => {
                let d = dir(s);
                mer_lost += usize::from(crate::verify::has_mer_maps(&d));
                std::fs::remove_dir_all(&d).map_err(|e| PrepError::io(&d, e))?;
                progress.println(format!("broken, prepared again: {why}"));
                rebuilt.push((s.token.to_string(), why));
                todo.push(*s);
            }
        }
    }
    *existing = keep;
    Ok((rebuilt, mer_lost))
}

/// The samples of `--shard I/N` (all of `selected` without one) and the shard's record for
/// its index.
fn shard_selection(
    selected: Vec<&Sample>,
    shard: Option<Shard>,
) -> (Vec<&Sample>, Option<layout::ShardInfo>) {
    match shard {
        Some(sh) => {
            let (samples, scenes) = shard_samples(&selected, sh);
            (
                samples,
                Some(layout::ShardInfo {
                    index: sh.index,
                    count: sh.count,
                    scenes,
                }),
            )
        }
        None => (selected, None),
    }
}

/// Create the output folder, take its shared lock (held while the returned guard lives) and
/// remove the temporary folders of interrupted runs.
fn open_output(opts: &PrepareOptions) -> Result<depthsense_base::lock::OutputLock, PrepError> {
    std::fs::create_dir_all(&opts.out).map_err(|e| PrepError::io(&opts.out, e))?;
    // Several prepare processes (shards) may share one --out; `mer apply` and `index merge`
    // may not write it meanwhile (docs/guide/reliability.md).
    let writing = depthsense_base::lock::OutputLock::shared(&opts.out, "depthsense prepare")?;
    // Temporary folders of interrupted runs (never those of a running process).
    crate::index::remove_stale_temp_dirs(&opts.out);
    Ok(writing)
}

/// One version and one set of map settings per output folder: every index there must
/// agree before any work is done (and again when this run's entries are written). Returns
/// whether some index holds settings.
fn check_output_indexes(opts: &PrepareOptions, version: &str) -> Result<bool, PrepError> {
    let settings = settings_map(opts);
    let mut indexed = false;
    for p in crate::index::index_files(&opts.out)? {
        if let Some(ix) = crate::index::read_index(&p)? {
            crate::index::check_index(&p, &ix, version, &settings)?;
            indexed |= !ix.settings.is_empty();
        }
    }
    Ok(indexed)
}

/// One sample's token and how its preparation ended.
type SampleResult = (Token, Result<(), PrepError>);

/// Prepare `todo` on a pool of `opts.jobs` threads; each sample's result, in `todo`'s order.
fn prepare_all(
    job: &Job,
    todo: &[&Sample],
    progress: &depthsense_progress::Progress,
) -> Result<Vec<SampleResult>, PrepError> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(job.opts.jobs)
        .build()
        .map_err(PrepError::ThreadPool)?;
    Ok(pool.install(|| {
        todo.par_iter()
            .map(|s| {
                let r = prepare_one(job, s);
                progress.inc(1);
                (s.token, r)
            })
            .collect()
    }))
}

/// The run's summary and the tokens of its complete samples (the existing ones included).
fn summarise(existing: &[&Sample], results: Vec<SampleResult>) -> (PrepareSummary, HashSet<Token>) {
    let mut summary = PrepareSummary {
        skipped_existing: existing.len(),
        ..Default::default()
    };
    let mut ok: HashSet<Token> = existing.iter().map(|s| s.token).collect();
    for (t, r) in results {
        match r {
            Ok(()) => {
                summary.prepared += 1;
                ok.insert(t);
            }
            Err(e) => summary.failed.push((t.to_string(), e.to_string())),
        }
    }
    (summary, ok)
}

/// `--shard I/N`: the I-th of N disjoint parts of the selected samples, by scene (scene j of
/// the selection, in its order, goes to shard j mod N), so a scene's sweeps are read by one
/// process and the parts are balanced. Returns the shard's samples and its scene tokens.
pub fn shard_samples<'a>(selected: &[&'a Sample], shard: Shard) -> (Vec<&'a Sample>, Vec<String>) {
    let mut scene_order: Vec<Token> = Vec::new();
    let mut seen: HashSet<Token> = HashSet::new();
    for s in selected {
        if seen.insert(s.scene_token) {
            scene_order.push(s.scene_token);
        }
    }
    let mine: Vec<Token> = scene_order
        .iter()
        .enumerate()
        .filter(|(j, _)| j % shard.count == shard.index)
        .map(|(_, t)| *t)
        .collect();
    let mine_set: HashSet<Token> = mine.iter().copied().collect();
    (
        selected
            .iter()
            .copied()
            .filter(|s| mine_set.contains(&s.scene_token))
            .collect(),
        mine.iter().map(|t| t.to_string()).collect(),
    )
}

/// Settings that change the maps; a finished sample made with other values is not reused.
fn map_settings(opts: &PrepareOptions) -> Vec<(&'static str, serde_json::Value)> {
    vec![
        ("radar_sweeps", serde_json::json!(opts.radar_sweeps)),
        ("radar_channels", serde_json::json!(opts.radar_channels)),
        ("radar_filters", serde_json::json!(opts.radar_filters)),
        (
            "radar_velocity_compensation",
            serde_json::json!(opts.radar_velocity_compensation),
        ),
        ("lidar_sweeps_k", serde_json::json!(opts.lidar_sweeps)),
        ("dense_rules", serde_json::json!(DENSE_RULES)),
    ]
}

/// [`map_settings`] as stored in `index.json`.
pub fn settings_map(opts: &PrepareOptions) -> BTreeMap<String, serde_json::Value> {
    map_settings(opts)
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect()
}

fn check_settings(meta_path: &Path, opts: &PrepareOptions) -> Result<(), PrepError> {
    let bytes = std::fs::read(meta_path).map_err(|e| PrepError::io(meta_path, e))?;
    let meta: SampleMeta =
        serde_json::from_slice(&bytes).map_err(|source| PrepError::UnreadableMeta {
            path: meta_path.to_path_buf(),
            source,
        })?;
    for (k, v) in map_settings(opts) {
        let old = &meta.settings[k];
        if *old != v {
            return Err(PrepError::SettingsMismatch {
                path: meta_path.parent().unwrap_or(meta_path).to_path_buf(),
                what: k.to_string(),
                old: old.to_string(),
                new: v.to_string(),
            });
        }
    }
    Ok(())
}

/// Merge this run's complete samples into `O/index.json` (or the shard's
/// `index.shard-I-of-N.json`) under the folder's index lock; entries of other runs are kept.
fn write_index(
    nu: &NuScenes,
    opts: &PrepareOptions,
    samples: &[&Sample],
    ok: &HashSet<Token>,
    assignment: &crate::splits::SplitAssignment,
    shard: Option<layout::ShardInfo>,
) -> Result<(), PrepError> {
    let path = match &shard {
        Some(s) => opts.out.join(layout::shard_index_file(s.index, s.count)),
        None => opts.out.join(layout::INDEX_FILE),
    };
    let settings = settings_map(opts);
    let mut entries = Vec::new();
    let mut scene_splits: std::collections::HashMap<Token, Vec<String>> = Default::default();
    for s in samples.iter().filter(|s| ok.contains(&s.token)) {
        let scene = nu.get_scene(s.scene_token, "sample", s.token, "scene_token")?;
        let scene_tok = scene.token.to_string();
        let splits = scene_splits
            .entry(scene.token)
            .or_insert_with(|| assignment.splits_of(&scene_tok))
            .clone();
        entries.push(IndexEntry {
            sample_token: s.token.to_string(),
            scene_token: scene_tok,
            scene_name: scene.name.clone(),
            splits,
            conditions: conditions_of(&scene.description),
            dir: s.token.to_string(),
        });
    }
    let _lock = crate::index::lock_index(&opts.out)?;
    // Read again under the lock: another process may have written it since the start.
    let mut index = match crate::index::read_index(&path)? {
        Some(ix) => {
            crate::index::check_index(&path, &ix, &nu.version, &settings)?;
            ix
        }
        None => PreparedIndex::default(),
    };
    index.version = nu.version.clone();
    index.settings = settings;
    index.frame_size = Some([layout::FRAME_W, layout::FRAME_H]);
    index.split_source = match &assignment.lists_dir {
        Some(d) => format!("{}: {}", assignment.source, d.display()),
        None => assignment.source.clone(),
    };
    index.train_scenes = assignment.train_scenes.clone();
    index.val_scenes = assignment.val_scenes.clone();
    index.test_scenes = assignment.test_scenes.clone();
    index.shard = shard;
    crate::index::merge_entries(&mut index, entries);
    crate::index::write_index_file(&path, &index)
}

#[cfg(test)]
mod tests {
    use super::*;
    use depthsense_progress::Progress;
    use depthsense_synth::{generate, SynthConfig};

    /// A panic inside one sample fails that sample (named, with the file being read), leaves
    /// no folder for it, and every other sample of the run is prepared.
    #[test]
    fn a_panicking_sample_fails_alone() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("world");
        let cfg = SynthConfig {
            scenes: 2,
            keyframes_per_scene: 2,
            ..SynthConfig::tiny()
        };
        generate(&root, &cfg, &Progress::hidden()).unwrap();
        let nu = NuScenes::load(&root, &cfg.version_name).unwrap();
        let victim = nu.sample[1].token.to_string();
        PANIC_ON.lock().unwrap().push(victim.clone());
        let out = tmp.path().join("out");
        let opts = PrepareOptions {
            dataroot: root,
            version: cfg.version_name.clone(),
            out: out.clone(),
            radar_sweeps: 1,
            jobs: 2,
            ..Default::default()
        };
        let s = prepare(&opts, &Progress::hidden()).unwrap();
        PANIC_ON.lock().unwrap().retain(|t| *t != victim);
        assert_eq!(s.prepared, 3, "{:?}", s.failed);
        assert_eq!(s.failed.len(), 1);
        assert_eq!(s.failed[0].0, victim);
        assert!(
            s.failed[0].1.contains("panicked")
                && s.failed[0].1.contains("injected test panic")
                && s.failed[0].1.contains("LIDAR_TOP"),
            "{}",
            s.failed[0].1
        );
        assert!(!out.join(&victim).exists());
        let names: Vec<String> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(names.iter().all(|n| !n.starts_with(".tmp")), "{names:?}");
        let idx: PreparedIndex =
            serde_json::from_slice(&std::fs::read(out.join(layout::INDEX_FILE)).unwrap()).unwrap();
        assert_eq!(idx.samples.len(), 3);
        assert!(idx.samples.iter().all(|e| e.sample_token != victim));
        // A second run prepares the one that failed.
        let s2 = prepare(&opts, &Progress::hidden()).unwrap();
        assert_eq!((s2.prepared, s2.skipped_existing), (1, 3));
    }
}
