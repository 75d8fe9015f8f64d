//! Benchmark helpers for `depthsense bench data`: generated trainval-sized tables, a
//! multi-sweep world built from the real keyframe fixture, and the projection-only timing.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use depthsense_nuscenes::geometry::{cam_from_sensor, ego_from_sensor, Camera};
use depthsense_nuscenes::pcd::{read_lidar_pcd_bin, read_radar_pcd};
use depthsense_nuscenes::tables::{NuScenes, Token};
use depthsense_progress::Progress;
use serde_json::json;

use crate::error::PrepError;
use crate::maps::{self, Raster};
use crate::pipeline::{prepare_timed, PrepareOptions};

fn tok(kind: u32, i: u64) -> String {
    format!("{:08x}{:024x}", kind, i)
}

/// Row counts of the real v1.0-trainval tables.
pub const TRAINVAL_SAMPLE_DATA: u64 = 2_631_083;
pub const TRAINVAL_SAMPLES: u64 = 34_149;
pub const TRAINVAL_SCENES: u64 = 850;
pub const TRAINVAL_ANNOTATIONS: u64 = 1_166_187;

/// Write v1.0-trainval-sized tables (same row counts and record shapes, random-ish values)
/// into `dir/<version>/`, streaming so that generation itself needs little memory.
/// `scale` multiplies the row counts (1.0 = trainval). Returns the total bytes written.
pub fn generate_trainval_tables(dir: &Path, version: &str, scale: f64) -> Result<u64, PrepError> {
    let v = dir.join(version);
    std::fs::create_dir_all(&v).map_err(|e| PrepError::io(&v, e))?;
    let n = RowCounts {
        sample_data: (TRAINVAL_SAMPLE_DATA as f64 * scale) as u64,
        samples: ((TRAINVAL_SAMPLES as f64 * scale) as u64).max(1),
        scenes: ((TRAINVAL_SCENES as f64 * scale) as u64).max(1),
        annotations: (TRAINVAL_ANNOTATIONS as f64 * scale) as u64,
    };
    let mut w = TableWriter { dir: v, total: 0 };
    write_sensor_tables(&mut w)?;
    write_scene_tables(&mut w, &n)?;
    write_sample_data_tables(&mut w, &n)?;
    write_annotation_tables(&mut w, &n)?;
    Ok(w.total)
}

/// Row counts of the generated tables that follow the scale.
struct RowCounts {
    sample_data: u64,
    samples: u64,
    scenes: u64,
    annotations: u64,
}

/// Calibrated-sensor rows of the generated tables (not scaled).
const GEN_CALIBRATIONS: u64 = 10_200;

/// The 12 sensor channels of the generated tables (6 cameras, lidar, 5 radars).
const GEN_CHANNELS: [&str; 12] = [
    "CAM_FRONT",
    "CAM_FRONT_RIGHT",
    "CAM_FRONT_LEFT",
    "CAM_BACK",
    "CAM_BACK_LEFT",
    "CAM_BACK_RIGHT",
    "LIDAR_TOP",
    "RADAR_FRONT",
    "RADAR_FRONT_LEFT",
    "RADAR_FRONT_RIGHT",
    "RADAR_BACK_LEFT",
    "RADAR_BACK_RIGHT",
];

/// Streams JSON tables into one version folder, counting the row bytes written.
struct TableWriter {
    dir: PathBuf,
    total: u64,
}

impl TableWriter {
    /// Write `dir/<name>.json`: a JSON array of `n` rows, row `i` written by `row(i, buf)`.
    fn write(
        &mut self,
        name: &str,
        n: u64,
        row: &mut dyn FnMut(u64, &mut Vec<u8>),
    ) -> Result<(), PrepError> {
        let p = self.dir.join(format!("{name}.json"));
        let f = std::fs::File::create(&p).map_err(|e| PrepError::io(&p, e))?;
        let mut w = std::io::BufWriter::with_capacity(1 << 20, f);
        let mut buf = Vec::with_capacity(1024);
        w.write_all(b"[\n").map_err(|e| PrepError::io(&p, e))?;
        for i in 0..n {
            buf.clear();
            row(i, &mut buf);
            if i + 1 < n {
                buf.extend_from_slice(b",\n");
            }
            w.write_all(&buf).map_err(|e| PrepError::io(&p, e))?;
            self.total += buf.len() as u64;
        }
        w.write_all(b"\n]\n").map_err(|e| PrepError::io(&p, e))?;
        w.flush().map_err(|e| PrepError::io(&p, e))
    }
}

/// `sensor`, `calibrated_sensor` and `log`.
fn write_sensor_tables(w: &mut TableWriter) -> Result<(), PrepError> {
    w.write("sensor", 12, &mut |i, b| {
        let _ = write!(
            b,
            r#"{{"token": "{}", "channel": "{}", "modality": "{}"}}"#,
            tok(1, i),
            GEN_CHANNELS[i as usize],
            if i < 6 {
                "camera"
            } else if i == 6 {
                "lidar"
            } else {
                "radar"
            }
        );
    })?;
    w.write("calibrated_sensor", GEN_CALIBRATIONS, &mut |i, b| {
        let _ = write!(
            b,
            r#"{{"token": "{}", "sensor_token": "{}", "translation": [1.70079118954, 0.0159456324149, 1.51095763913], "rotation": [0.4998015430569128, -0.5030316162024876, 0.4997798114386805, -0.49737083824542755], "camera_intrinsic": {}}}"#,
            tok(2, i),
            tok(1, i % 12),
            if i % 12 < 6 {
                "[[1266.417203046554, 0.0, 816.2670197447984], [0.0, 1266.417203046554, 491.50706579294757], [0.0, 0.0, 1.0]]"
            } else {
                "[]"
            }
        );
    })?;
    w.write("log", 68, &mut |i, b| {
        let _ = write!(
            b,
            r#"{{"token": "{}", "logfile": "n015-2018-07-24-11-22-45+0800", "vehicle": "n015", "date_captured": "2018-07-24", "location": "singapore-onenorth"}}"#,
            tok(3, i)
        );
    })?;
    Ok(())
}

/// `scene` and `sample` (40 samples per scene).
fn write_scene_tables(w: &mut TableWriter, n: &RowCounts) -> Result<(), PrepError> {
    w.write("scene", n.scenes, &mut |i, b| {
        let _ = write!(
            b,
            r#"{{"token": "{}", "log_token": "{}", "nbr_samples": 40, "first_sample_token": "{}", "last_sample_token": "{}", "name": "scene-{:04}", "description": "{}"}}"#,
            tok(4, i),
            tok(3, i % 68),
            tok(5, i * 40),
            tok(5, i * 40 + 39),
            i,
            if i % 10 == 0 {
                "Night, parked cars"
            } else {
                "Rain, intersection"
            }
        );
    })?;
    w.write("sample", n.samples, &mut |i, b| {
        let _ = write!(
            b,
            r#"{{"token": "{}", "timestamp": {}, "prev": "{}", "next": "{}", "scene_token": "{}"}}"#,
            tok(5, i),
            1532402927647951u64 + i * 500_000,
            if i % 40 == 0 {
                String::new()
            } else {
                tok(5, i - 1)
            },
            tok(5, i + 1),
            tok(4, (i / 40) % n.scenes)
        );
    })?;
    Ok(())
}

/// `sample_data` (12 channels in turn, every sixth round a keyframe) and one `ego_pose` each.
fn write_sample_data_tables(w: &mut TableWriter, n: &RowCounts) -> Result<(), PrepError> {
    w.write("sample_data", n.sample_data, &mut |i, b| {
        let ch = (i % 12) as usize;
        let key = (i / 12) % 6 == 0;
        let _ = write!(
            b,
            r#"{{"token": "{}", "sample_token": "{}", "ego_pose_token": "{}", "calibrated_sensor_token": "{}", "timestamp": {}, "fileformat": "{}", "is_key_frame": {}, "height": {}, "width": {}, "filename": "{}/{}/n015-2018-07-24-11-22-45+0800__{}__{}.{}", "prev": "{}", "next": "{}"}}"#,
            tok(6, i),
            tok(5, (i / 72) % n.samples),
            tok(7, i),
            tok(2, i % GEN_CALIBRATIONS),
            1532402927612460u64 + i * 3000,
            if ch < 6 { "jpg" } else { "pcd" },
            key,
            if ch < 6 { 900 } else { 0 },
            if ch < 6 { 1600 } else { 0 },
            if key { "samples" } else { "sweeps" },
            GEN_CHANNELS[ch],
            GEN_CHANNELS[ch],
            1532402927612460u64 + i * 3000,
            if ch < 6 {
                "jpg"
            } else if ch == 6 {
                "pcd.bin"
            } else {
                "pcd"
            },
            if i < 12 {
                String::new()
            } else {
                tok(6, i - 12)
            },
            tok(6, i + 12)
        );
    })?;
    w.write("ego_pose", n.sample_data, &mut |i, b| {
        let _ = write!(
            b,
            r#"{{"token": "{}", "timestamp": {}, "rotation": [0.5720063498929273, -0.0021434844534272707, 0.011564094980151613, -0.8201648693182716], "translation": [{}, {}, 0.0]}}"#,
            tok(7, i),
            1532402927612460u64 + i * 3000,
            411.4199861830012 + (i % 1000) as f64 * 0.1,
            1181.197175631848 - (i % 997) as f64 * 0.07
        );
    })?;
    Ok(())
}

/// `category`, `attribute`, `instance` (18 annotations each) and `sample_annotation`.
fn write_annotation_tables(w: &mut TableWriter, n: &RowCounts) -> Result<(), PrepError> {
    w.write("category", 23, &mut |i, b| {
        let _ = write!(
            b,
            r#"{{"token": "{}", "name": "vehicle.car.{i}", "description": "generated"}}"#,
            tok(8, i)
        );
    })?;
    w.write("attribute", 8, &mut |i, b| {
        let _ = write!(
            b,
            r#"{{"token": "{}", "name": "{}", "description": "generated"}}"#,
            tok(9, i),
            [
                "vehicle.moving",
                "vehicle.stopped",
                "vehicle.parked",
                "cycle.with_rider",
                "cycle.without_rider",
                "pedestrian.sitting_lying_down",
                "pedestrian.standing",
                "pedestrian.moving"
            ][i as usize]
        );
    })?;
    let n_inst = (n.annotations / 18).max(1);
    w.write("instance", n_inst, &mut |i, b| {
        let _ = write!(
            b,
            r#"{{"token": "{}", "category_token": "{}", "nbr_annotations": 18, "first_annotation_token": "{}", "last_annotation_token": "{}"}}"#,
            tok(10, i),
            tok(8, i % 23),
            tok(11, i * 18),
            tok(11, i * 18 + 17)
        );
    })?;
    w.write("sample_annotation", n.annotations, &mut |i, b| {
        let _ = write!(
            b,
            r#"{{"token": "{}", "sample_token": "{}", "instance_token": "{}", "visibility_token": "4", "attribute_tokens": ["{}"], "translation": [373.256, 1130.419, 0.8], "size": [0.621, 0.669, 1.642], "rotation": [0.9831098797903927, 0.0, 0.0, -0.18301629506281616], "prev": "{}", "next": "{}", "num_lidar_pts": 5, "num_radar_pts": 0}}"#,
            tok(11, i),
            tok(5, (i / 34) % n.samples),
            tok(10, (i / 18) % n_inst),
            tok(9, i % 8),
            if i % 18 == 0 {
                String::new()
            } else {
                tok(11, i - 1)
            },
            if i % 18 == 17 {
                String::new()
            } else {
                tok(11, i + 1)
            }
        );
    })?;
    Ok(())
}

/// Peak resident memory of this process (VmHWM), bytes; None off Linux.
pub fn peak_rss_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let l = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    l.split_whitespace()
        .nth(1)?
        .parse::<u64>()
        .ok()
        .map(|k| k * 1024)
}

/// CPU time (user + system) of this process so far, seconds; None off Linux.
pub fn process_cpu_s() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// The 1-minute load average (to judge timings on a shared machine).
pub fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Reset the peak-RSS counter (Linux `clear_refs` 5); false when unsupported.
pub fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// Build a nuScenes-format world of `scenes` × `samples_per_scene` keyframes from the real
/// fixture keyframe (`fixture` = nuscenes-kf0): every keyframe reuses the real camera, lidar
/// and radar files, with `lidar_sweeps_between` lidar sweeps between keyframes and
/// `radar_sweeps_between` radar sweeps per channel (three front radars; the side channels
/// get the RADAR_FRONT calibration yawed by ±30°). The ego drives straight at 10 m/s.
pub fn build_fixture_world(
    fixture: &Path,
    out: &Path,
    samples: usize,
    lidar_sweeps_between: usize,
    radar_sweeps_between: usize,
) -> Result<PathBuf, PrepError> {
    if samples == 0 {
        return Err(PrepError::BenchNoKeyframes);
    }
    let nu = NuScenes::load(fixture, "v1.0-mini")?;
    let [cam, lidar, radar] = fixture_keyframes(&nu, fixture)?;
    copy_fixture_files(
        &nu,
        out,
        [
            (cam, "samples/CAM_FRONT"),
            (lidar, "samples/LIDAR_TOP"),
            (radar, "samples/RADAR_FRONT"),
        ],
    )?;
    let [cc, lc, rc] = fixture_calibrations(&nu, [cam, lidar, radar])?;
    let ep = nu
        .get_ego_pose(
            lidar.ego_pose_token,
            "sample_data",
            lidar.token,
            "ego_pose_token",
        )?
        .clone();
    let v = out.join("v1.0-bench");
    std::fs::create_dir_all(&v).map_err(|e| PrepError::io(&v, e))?;
    let (sensors, calibs) = bench_sensor_tables(&cc, &lc, &rc);
    let mut ego = EgoDrive::new(&ep)?;
    let chans = channel_chains(
        [&cam.filename, &lidar.filename, &radar.filename],
        lidar_sweeps_between,
        radar_sweeps_between,
    );
    let sd_rows = sample_data_rows(&chans, samples, &mut ego);
    let (scene, log) = scene_and_log_tables(samples);
    write_json_tables(
        &v,
        [
            ("sensor", sensors),
            ("calibrated_sensor", calibs),
            ("scene", scene),
            ("log", log),
            ("sample", json!(sample_rows(samples))),
            ("sample_data", json!(sd_rows)),
            ("ego_pose", json!(ego.rows)),
        ],
    )?;
    Ok(out.to_path_buf())
}

/// The CAM_FRONT, LIDAR_TOP and RADAR_FRONT keyframes of the nuscenes-kf0 fixture's sample.
fn fixture_keyframes<'a>(
    nu: &'a NuScenes,
    fixture: &Path,
) -> Result<[&'a depthsense_nuscenes::tables::SampleData; 3], PrepError> {
    let st = Token::parse("ca9a282c9e77460f8360f564131a8af5");
    let need = |ch: &str, missing: &'static str| {
        nu.keyframe(st, ch).ok_or_else(|| PrepError::NotKf0Fixture {
            path: fixture.display().to_string(),
            missing,
        })
    };
    Ok([
        need("CAM_FRONT", "CAM_FRONT keyframe")?,
        need("LIDAR_TOP", "LIDAR_TOP keyframe")?,
        need("RADAR_FRONT", "RADAR_FRONT keyframe")?,
    ])
}

/// The calibrations of the fixture's keyframes, in their order.
fn fixture_calibrations(
    nu: &NuScenes,
    keyframes: [&depthsense_nuscenes::tables::SampleData; 3],
) -> Result<[depthsense_nuscenes::tables::CalibratedSensor; 3], PrepError> {
    let calib = |sd: &depthsense_nuscenes::tables::SampleData| {
        nu.get_calibrated_sensor(sd.calibrated_sensor_token, "sample_data", sd.token, "cst")
            .cloned()
    };
    let [cam, lidar, radar] = keyframes;
    Ok([calib(cam)?, calib(lidar)?, calib(radar)?])
}

/// The bench world's one scene (`samples` keyframes) and its log.
fn scene_and_log_tables(samples: usize) -> (serde_json::Value, serde_json::Value) {
    let scene = json!([{"token": tok(4, 0), "log_token": tok(3, 0), "nbr_samples": samples, "first_sample_token": tok(5, 0), "last_sample_token": tok(5, samples as u64 - 1), "name": "bench-0", "description": "Generated from the nuscenes-kf0 fixture"}]);
    let log = json!([{"token": tok(3, 0), "logfile": "bench", "vehicle": "n015", "date_captured": "2018-07-24", "location": "singapore-onenorth"}]);
    (scene, log)
}

/// Copy the fixture keyframe's files (sample data, folder under `out`) into `out`, unless
/// already there.
fn copy_fixture_files(
    nu: &NuScenes,
    out: &Path,
    files: [(&depthsense_nuscenes::tables::SampleData, &str); 3],
) -> Result<(), PrepError> {
    for (sd, sub) in files {
        let src = nu.path_of(sd);
        let dst_dir = out.join(sub);
        std::fs::create_dir_all(&dst_dir).map_err(|e| PrepError::io(&dst_dir, e))?;
        let dst = out.join(&*sd.filename);
        if !dst.exists() {
            std::fs::copy(&src, &dst).map_err(|e| PrepError::io(&src, e))?;
        }
    }
    Ok(())
}

/// The rotation `q` (w, x, y, z) followed by a yaw of `deg` degrees about the sensor's z axis.
fn yawed(q: [f64; 4], deg: f64) -> [f64; 4] {
    let h = deg.to_radians() / 2.0;
    let r = [h.cos(), 0.0, 0.0, h.sin()];
    // q ⊗ r (w, x, y, z)
    [
        q[0] * r[0] - q[3] * r[3],
        q[1] * r[0] + q[2] * r[3],
        q[2] * r[0] - q[1] * r[3],
        q[3] * r[0] + q[0] * r[3],
    ]
}

/// The bench world's `sensor` and `calibrated_sensor` tables: the fixture's camera, lidar and
/// front radar, and two side radars with the front radar's calibration yawed by ±30°.
fn bench_sensor_tables(
    cc: &depthsense_nuscenes::tables::CalibratedSensor,
    lc: &depthsense_nuscenes::tables::CalibratedSensor,
    rc: &depthsense_nuscenes::tables::CalibratedSensor,
) -> (serde_json::Value, serde_json::Value) {
    let yaw = |deg: f64| yawed(rc.rotation, deg);
    let sensors = json!([
        {"token": tok(1, 0), "channel": "CAM_FRONT", "modality": "camera"},
        {"token": tok(1, 1), "channel": "LIDAR_TOP", "modality": "lidar"},
        {"token": tok(1, 2), "channel": "RADAR_FRONT", "modality": "radar"},
        {"token": tok(1, 3), "channel": "RADAR_FRONT_LEFT", "modality": "radar"},
        {"token": tok(1, 4), "channel": "RADAR_FRONT_RIGHT", "modality": "radar"},
    ]);
    let calibs = json!([
        {"token": tok(2, 0), "sensor_token": tok(1, 0), "translation": cc.translation, "rotation": cc.rotation, "camera_intrinsic": cc.camera_intrinsic},
        {"token": tok(2, 1), "sensor_token": tok(1, 1), "translation": lc.translation, "rotation": lc.rotation, "camera_intrinsic": []},
        {"token": tok(2, 2), "sensor_token": tok(1, 2), "translation": rc.translation, "rotation": rc.rotation, "camera_intrinsic": []},
        {"token": tok(2, 3), "sensor_token": tok(1, 3), "translation": [3.0, 0.6, 0.5], "rotation": yaw(30.0), "camera_intrinsic": []},
        {"token": tok(2, 4), "sensor_token": tok(1, 4), "translation": [3.0, -0.6, 0.5], "rotation": yaw(-30.0), "camera_intrinsic": []},
    ]);
    (sensors, calibs)
}

/// Timestamp of keyframe `k` of the bench world, µs (2 Hz).
fn key_time_us(k: usize) -> i64 {
    1_600_000_000_000_000i64 + k as i64 * 500_000
}

/// The ego's `ego_pose` rows: the fixture pose moved straight ahead at 10 m/s.
struct EgoDrive {
    rot: [f64; 4],
    t0: [f64; 3],
    fwd: [f64; 3],
    rows: Vec<serde_json::Value>,
    next_id: u64,
}

impl EgoDrive {
    /// Start at the fixture's ego pose (forward = the first column of its rotation).
    fn new(ep: &depthsense_nuscenes::tables::EgoPose) -> Result<EgoDrive, PrepError> {
        let (rot, t0) = (ep.rotation, ep.translation);
        let rm = depthsense_nuscenes::geometry::rotation_from_wxyz(rot, "fixture ego")?;
        let fwd = [rm[0][0], rm[1][0], rm[2][0]];
        Ok(EgoDrive {
            rot,
            t0,
            fwd,
            rows: Vec::new(),
            next_id: 0,
        })
    }

    /// Add the pose at `ts` (µs) and return its token.
    fn pose(&mut self, ts: i64) -> String {
        let (rot, t0, fwd) = (self.rot, self.t0, self.fwd);
        let d = (ts - key_time_us(0)) as f64 * 1e-6 * 10.0;
        let id = tok(7, self.next_id);
        self.next_id += 1;
        self.rows.push(json!({"token": id, "timestamp": ts, "rotation": rot, "translation": [t0[0] + fwd[0] * d, t0[1] + fwd[1] * d, t0[2]]}));
        id
    }
}

/// Channel chain: (channel, calib index, file, sweeps between keyframes, offset µs).
type ChannelChain<'a> = (&'static str, u64, &'a str, usize, i64);

/// The bench world's channel chains; `files` = the camera, lidar and radar files.
fn channel_chains(
    files: [&str; 3],
    lidar_sweeps_between: usize,
    radar_sweeps_between: usize,
) -> [ChannelChain<'_>; 5] {
    let [cam, lidar, radar] = files;
    [
        ("CAM_FRONT", 0, cam, 0, -35_000),
        ("LIDAR_TOP", 1, lidar, lidar_sweeps_between, 0),
        ("RADAR_FRONT", 2, radar, radar_sweeps_between, 16_000),
        ("RADAR_FRONT_LEFT", 3, radar, radar_sweeps_between, 20_000),
        ("RADAR_FRONT_RIGHT", 4, radar, radar_sweeps_between, 24_000),
    ]
}

/// The `sample_data` rows of every channel chain, chain after chain: `between` extra sweeps
/// before the first keyframe (so that every keyframe has history), the keyframes with
/// `between` sweeps between them, `between` after the last; one ego pose each.
fn sample_data_rows(
    chans: &[ChannelChain],
    samples: usize,
    ego: &mut EgoDrive,
) -> Vec<serde_json::Value> {
    let mut sd_rows = Vec::new();
    let mut sd_id = 0u64;
    for (ci, (_ch, calib, file, between, off)) in chans.iter().enumerate() {
        let per = between + 1;
        let total = (samples - 1) * per + 1;
        // extra sweeps before the first keyframe so that every keyframe has history
        let pre = *between;
        let base = sd_id;
        let n = pre + total + pre;
        for j in 0..n {
            let k_rel = j as i64 - pre as i64;
            let ts = key_time_us(0) + off + k_rel * 500_000 / per as i64;
            let key = k_rel >= 0
                && (k_rel as usize).is_multiple_of(per)
                && (k_rel as usize) / per < samples;
            let sample = if key {
                tok(5, (k_rel as usize / per) as u64)
            } else {
                String::new()
            };
            let ego_pose_token = ego.pose(ts);
            sd_rows.push(json!({
                "token": tok(6, base + j as u64), "sample_token": sample, "ego_pose_token": ego_pose_token,
                "calibrated_sensor_token": tok(2, *calib), "timestamp": ts, "fileformat": if ci == 0 {"jpg"} else {"pcd"},
                "is_key_frame": key, "height": if ci == 0 {900} else {0}, "width": if ci == 0 {1600} else {0},
                "filename": file, "prev": if j == 0 { String::new() } else { tok(6, base + j as u64 - 1) },
                "next": if j + 1 == n { String::new() } else { tok(6, base + j as u64 + 1) },
            }));
        }
        sd_id += n as u64;
    }
    sd_rows
}

/// The `sample` rows: `samples` keyframes of one scene.
fn sample_rows(samples: usize) -> Vec<serde_json::Value> {
    let mut sample_rows = Vec::new();
    for k in 0..samples {
        sample_rows.push(json!({"token": tok(5, k as u64), "timestamp": key_time_us(k), "prev": if k == 0 { String::new() } else { tok(5, k as u64 - 1) }, "next": if k + 1 == samples { String::new() } else { tok(5, k as u64 + 1) }, "scene_token": tok(4, 0)}));
    }
    sample_rows
}

/// Write each (name, rows) as `v/<name>.json`.
fn write_json_tables(v: &Path, tables: [(&str, serde_json::Value); 7]) -> Result<(), PrepError> {
    for (name, val) in tables {
        let p = v.join(format!("{name}.json"));
        std::fs::write(
            &p,
            serde_json::to_vec(&val).map_err(|e| PrepError::encode(p.display(), e))?,
        )
        .map_err(|e| PrepError::io(&p, e))?;
    }
    Ok(())
}

/// Projection + rasterisation of one keyframe (sparse lidar, low-height mask, keyframe
/// surface, radar raw + height-extended), files already decoded. Returns the median seconds
/// over `reps` repetitions and the lidar/radar point counts.
pub fn time_projection(fixture: &Path, reps: usize) -> Result<serde_json::Value, PrepError> {
    let nu = NuScenes::load(fixture, "v1.0-mini")?;
    let kf = projection_keyframe(&nu, fixture)?;
    let lidar = read_lidar_pcd_bin(&nu.path_of(kf.lidar_sd))?;
    let radar = read_radar_pcd(&nu.path_of(kf.radar_sd))?;
    let mut times = Vec::with_capacity(reps);
    let mut sink = 0u64;
    for _ in 0..reps.max(1) {
        let t = Instant::now();
        let check = project_keyframe_once(&nu, &kf, &lidar, &radar)?;
        times.push(t.elapsed().as_secs_f64());
        sink += check;
    }
    times.sort_by(|a, b| a.total_cmp(b));
    Ok(json!({
        "median_ms": times[times.len() / 2] * 1e3,
        "min_ms": times[0] * 1e3,
        "reps": times.len(),
        "lidar_points": lidar.points.len(),
        "radar_sweeps": 15,
        "radar_points_per_sweep": radar.points.len(),
        "checksum": sink,
    }))
}

/// The nuscenes-kf0 keyframe that [`time_projection`] projects.
struct ProjectionKeyframe<'a> {
    cam_sd: &'a depthsense_nuscenes::tables::SampleData,
    lidar_sd: &'a depthsense_nuscenes::tables::SampleData,
    radar_sd: &'a depthsense_nuscenes::tables::SampleData,
    /// CAM_FRONT at full resolution (1600x900).
    cam: Camera,
}

/// The fixture's CAM_FRONT, LIDAR_TOP and RADAR_FRONT keyframes and camera model.
fn projection_keyframe<'a>(
    nu: &'a NuScenes,
    fixture: &Path,
) -> Result<ProjectionKeyframe<'a>, PrepError> {
    let st = Token::parse("ca9a282c9e77460f8360f564131a8af5");
    let miss = |missing: &'static str| PrepError::NotKf0Fixture {
        path: fixture.display().to_string(),
        missing,
    };
    let need = |ch: &str, missing| nu.keyframe(st, ch).ok_or_else(|| miss(missing));
    let cam_sd = need("CAM_FRONT", "CAM_FRONT keyframe")?;
    let lidar_sd = need("LIDAR_TOP", "LIDAR_TOP keyframe")?;
    let radar_sd = need("RADAR_FRONT", "RADAR_FRONT keyframe")?;
    let cs = nu.get_calibrated_sensor(
        cam_sd.calibrated_sensor_token,
        "sample_data",
        cam_sd.token,
        "calibrated_sensor_token",
    )?;
    let cam = Camera::from_intrinsic(
        &cs.camera_intrinsic
            .ok_or_else(|| miss("CAM_FRONT camera intrinsic"))?,
        1600,
        900,
    );
    Ok(ProjectionKeyframe {
        cam_sd,
        lidar_sd,
        radar_sd,
        cam,
    })
}

/// One timed repetition of [`time_projection`]; returns a checksum of its results (so that
/// nothing is optimised away).
fn project_keyframe_once(
    nu: &NuScenes,
    kf: &ProjectionKeyframe,
    lidar: &depthsense_nuscenes::pcd::LidarScan,
    radar: &depthsense_nuscenes::pcd::RadarScan,
) -> Result<u64, PrepError> {
    let (cam_sd, lidar_sd, radar_sd, cam) = (kf.cam_sd, kf.lidar_sd, kf.radar_sd, &kf.cam);
    let mut sink = 0u64;
    let pts: Vec<[f32; 3]> = lidar.points.iter().map(|p| [p[0], p[1], p[2]]).collect();
    let c_l = cam_from_sensor(nu, lidar_sd, cam_sd)?;
    let e_l = ego_from_sensor(nu, lidar_sd)?.to_f32();
    let r = maps::project_points(&pts, &c_l, cam, |i| {
        depthsense_nuscenes::geometry::apply_f32(&e_l, pts[i])[2]
    });
    let mask = maps::lowheight_mask(&r);
    // The keyframe surface that other sweeps are judged against (K > 0).
    let surface = maps::KeyframeSurface::new(&r.depth_m);
    sink += (surface.judge(400, 175, 10.0) == maps::Visibility::Hidden) as u64;
    // 15 radar sweeps (5 sweeps × 3 channels) of the same file.
    let (rp, _) = radar.filtered(true);
    let c_r = cam_from_sensor(nu, radar_sd, cam_sd)?.to_f32();
    let mut raw = Raster::default();
    let mut hm = Raster::default();
    for _ in 0..15 {
        let pc: Vec<[f32; 3]> = maps::radar_positions(&rp, None)
            .iter()
            .map(|q| depthsense_nuscenes::geometry::apply_f32(&c_r, *q))
            .collect();
        maps::radar_maps(&pc, cam, &mut raw, &mut hm);
    }
    sink += mask[0] as u64 + raw.in_frame;
    Ok(sink)
}

/// Settings of `depthsense bench data`.
#[derive(Debug, Clone)]
pub struct BenchDataConfig {
    pub fixture: PathBuf,
    pub tables_scale: f64,
    pub skip_tables: bool,
    pub samples: usize,
    pub lidar_k: Vec<usize>,
    pub jobs: usize,
    pub work: Option<PathBuf>,
}

/// Run the data benchmarks in a scratch directory (removed afterwards); returns the report.
pub fn run_bench_data(cfg: &BenchDataConfig) -> Result<serde_json::Value, PrepError> {
    let work = cfg
        .work
        .clone()
        .unwrap_or_else(std::env::temp_dir)
        .join(format!("depthsense-bench-data-{}", std::process::id()));
    std::fs::create_dir_all(&work).map_err(|e| PrepError::io(&work, e))?;
    let res = run_in(cfg, &work);
    let _ = std::fs::remove_dir_all(&work);
    res
}

/// The data benchmarks in `work`: table loading (unless skipped), projection of one
/// keyframe, and `prepare` of the fixture world for each K.
fn run_in(a: &BenchDataConfig, work: &Path) -> Result<serde_json::Value, PrepError> {
    let mut report = json!({
        "load_average_1min_at_start": load_average(),
        "machine": format!("{} logical cores", std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)),
    });
    if !a.skip_tables {
        report["tables"] = bench_tables(a, work)?;
    }
    report["projection_one_keyframe"] = time_projection(&a.fixture, 50)?;
    let world = work.join("world");
    build_fixture_world(&a.fixture, &world, a.samples, 9, 6)?;
    let mut runs = Vec::new();
    for &k in &a.lidar_k {
        runs.push(bench_prepare(a, work, &world, k)?);
    }
    report["prepare"] = json!(runs);
    Ok(report)
}

/// Generate trainval-sized tables, time their loading (wall, CPU, peak memory), remove them.
fn bench_tables(a: &BenchDataConfig, work: &Path) -> Result<serde_json::Value, PrepError> {
    eprintln!(
        "generating trainval-sized tables (scale {}) …",
        a.tables_scale
    );
    let t = Instant::now();
    let bytes = generate_trainval_tables(work, "v1.0-gen", a.tables_scale)?;
    let gen_s = t.elapsed().as_secs_f64();
    let reset = reset_peak_rss();
    let rss0 = peak_rss_bytes().unwrap_or(0);
    let cpu0 = process_cpu_s().unwrap_or(0.0);
    let t = Instant::now();
    let nu = NuScenes::load(work, "v1.0-gen")?;
    let load_s = t.elapsed().as_secs_f64();
    let load_cpu_s = process_cpu_s().unwrap_or(0.0) - cpu0;
    let peak = peak_rss_bytes().unwrap_or(0);
    let counts: serde_json::Map<String, serde_json::Value> = nu
        .row_counts()
        .into_iter()
        .map(|(k, v)| (k.to_string(), json!(v)))
        .collect();
    drop(nu);
    std::fs::remove_dir_all(work.join("v1.0-gen")).map_err(|e| PrepError::io(work, e))?;
    let tables = json!({
        "json_bytes": bytes, "generate_s": gen_s, "load_s": load_s, "load_cpu_s": load_cpu_s,
        "peak_rss_bytes": peak, "rss_before_load_bytes": rss0, "peak_reset_ok": reset,
        "rows": counts,
    });
    eprintln!(
        "tables: {load_s:.2} s, peak RSS {:.0} MB",
        peak as f64 / 1e6
    );
    Ok(tables)
}

/// `prepare` the fixture world `world` with K = `k` (5 radar sweeps): throughput and the time
/// per stage; its output folder is removed afterwards.
fn bench_prepare(
    a: &BenchDataConfig,
    work: &Path,
    world: &Path,
    k: usize,
) -> Result<serde_json::Value, PrepError> {
    let out = work.join(format!("prepared-k{k}"));
    let opts = PrepareOptions {
        dataroot: world.to_path_buf(),
        version: "v1.0-bench".into(),
        out: out.clone(),
        lidar_sweeps: k,
        radar_sweeps: 5,
        jobs: a.jobs,
        ..Default::default()
    };
    let cpu0 = process_cpu_s().unwrap_or(0.0);
    let t = Instant::now();
    let (s, times) = prepare_timed(&opts, &Progress::hidden())?;
    let secs = t.elapsed().as_secs_f64();
    let cpu_s = process_cpu_s().unwrap_or(0.0) - cpu0;
    if let Some((t, r)) = s.failed.first() {
        return Err(PrepError::BenchPrepareFailed {
            sample: t.to_string(),
            reason: r.to_string(),
        });
    }
    eprintln!("prepare K={k}: {:.1} keyframes/s", s.prepared as f64 / secs);
    let n = s.prepared.max(1) as f64;
    let run = json!({
        "lidar_sweeps_k": k, "radar_sweeps": 5, "radar_channels": 3,
        "keyframes": s.prepared, "seconds": secs, "cpu_s": cpu_s, "keyframes_per_s": s.prepared as f64 / secs,
        "per_keyframe_ms_summed_over_threads": {
            "decode": times.decode_s / n * 1e3, "project": times.project_s / n * 1e3,
            "encode": times.encode_s / n * 1e3, "write": times.write_s / n * 1e3,
        },
    });
    std::fs::remove_dir_all(&out).map_err(|e| PrepError::io(&out, e))?;
    Ok(run)
}
