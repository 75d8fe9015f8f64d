//! Planning the sensor timeline of every scene, rendering all frames in parallel and writing
//! the dataroot: `<version>/*.json`, `samples/`, `sweeps/`, `truth/`, `maps/`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use depthsense_nuscenes::depth_png::{encode_png, DepthMap};
use depthsense_nuscenes::pcd::{encode_lidar_pcd_bin, encode_radar_pcd_binary};
use glam::{DQuat, DVec2};
use rayon::prelude::*;

use crate::calib::{self, Mount, IMG_H, IMG_W};
use crate::rng::{hash_str, name_token, token, Rng};
use crate::tables::*;
use crate::world::{ActorKind, ActorState, Ground, Motion, World, STATIC_OBJ_BASE};
use crate::{camera, lidar, radar, JpegError, SynthConfig, SynthError, SynthSummary, Weather};

/// File name of the marker written at the dataroot (config + summary).
pub const MARKER_FILE: &str = ".depthsense-synth.json";
/// Truth folder (per-pixel depth of every CAM_FRONT keyframe).
pub const TRUTH_DIR: &str = "truth";
/// Annotate actors within this distance of the ego.
const ANNOTATE_RANGE_M: f64 = 70.0;
/// Lidar sweeps before the first / after the last keyframe.
const LIDAR_PAD: usize = 5;
/// Map resolution (m per pixel) of the semantic prior PNG; load with
/// `NuScenes(..., map_resolution=1.0)` to query it.
pub const MAP_RES_M: f64 = 1.0;

const T_BASE_US: i64 = 1_700_000_000_000_000;

fn ts_us(scene: usize, t: f64) -> i64 {
    T_BASE_US + scene as i64 * 3_600_000_000 + (t * 1e6).round() as i64
}

fn q_wxyz(q: DQuat) -> [f64; 4] {
    [q.w, q.x, q.y, q.z]
}

#[derive(Debug, Clone)]
enum JobKind {
    /// The truth depth map's path when written, and the camera's rays per pixel side.
    Cam {
        truth: Option<String>,
        scale: u32,
        jpeg_420: bool,
    },
    Lidar,
    Radar {
        mount: Mount,
    },
}

#[derive(Debug, Clone)]
struct Job {
    scene: usize,
    kind: JobKind,
    t: f64,
    /// sample_data token (also the ego_pose token).
    token: String,
    filename: String,
    salt: u64,
}

#[derive(Default)]
struct JobOut {
    bytes: u64,
    /// Points per object (keyframe annotation counts).
    counts: Vec<(u32, u32)>,
}

struct ScenePlan {
    world: World,
    logfile: String,
    /// Keyframe times (lidar) and sample tokens.
    kf_t: Vec<f64>,
    sample_tokens: Vec<String>,
}

/// The condition of each scene: a balanced, deterministic allocation of the mix.
pub fn allocate_conditions(n: usize, mix: &[(Weather, f64)]) -> Vec<Weather> {
    let total: f64 = mix.iter().map(|m| m.1.max(0.0)).sum();
    let mut given = vec![0usize; mix.len()];
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        // Pick the condition furthest behind its quota.
        let mut best = 0;
        let mut best_def = f64::NEG_INFINITY;
        for (j, m) in mix.iter().enumerate() {
            let quota = (i + 1) as f64 * m.1.max(0.0) / total;
            let def = quota - given[j] as f64;
            if m.1 > 0.0 && def > best_def + 1e-12 {
                best_def = def;
                best = j;
            }
        }
        given[best] += 1;
        out.push(mix[best].0);
    }
    out
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> SynthError + '_ {
    move |source| SynthError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Generate the world into `out` (see [`crate::generate`]).
pub fn generate(
    out: &Path,
    cfg: &SynthConfig,
    progress: &depthsense_progress::Progress,
) -> Result<SynthSummary, SynthError> {
    let start = Instant::now();
    cfg.validate()?;
    // Refuse to overwrite anything that is not a previous synthetic world.
    if out.exists() {
        let non_empty = std::fs::read_dir(out)
            .map_err(io_err(out))?
            .next()
            .is_some();
        if non_empty && !out.join(MARKER_FILE).exists() {
            return Err(SynthError::Exists(out.to_path_buf()));
        }
    }
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent).map_err(io_err(&parent))?;
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "synth".into());
    let tmp = parent.join(format!(".{name}.synth-tmp-{}", std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io_err(&tmp))?;
    }
    let result = generate_into(&tmp, cfg, progress);
    match result {
        Ok(mut summary) => {
            if out.exists() {
                std::fs::remove_dir_all(out).map_err(io_err(out))?;
            }
            std::fs::rename(&tmp, out).map_err(io_err(out))?;
            summary.version_dir = out.join(&cfg.version_name);
            summary.seconds = start.elapsed().as_secs_f64();
            Ok(summary)
        }
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            Err(e)
        }
    }
}

fn generate_into(
    root: &Path,
    cfg: &SynthConfig,
    progress: &depthsense_progress::Progress,
) -> Result<SynthSummary, SynthError> {
    let seed = cfg.seed;
    let m = cfg.keyframes_per_scene;
    let weathers = allocate_conditions(cfg.scenes, &cfg.conditions);
    let mounts = calib::all_mounts();

    // Fixed tables.
    let mut tb = Tables::default();
    push_fixed_tables(&mut tb, &mounts);
    let map_token = token(seed, &[hash_str("map")]);

    // Plan scenes.
    let plans = plan_scenes(seed, m, &weathers);
    let tl = plan_frames(&mut tb, cfg, &plans, &mounts);

    create_dirs(root, &mounts, &cfg.version_name)?;
    let outs_ok = render_frames(root, cfg, &tl.jobs, &plans, progress)?;
    let mut bytes: u64 = outs_ok.iter().map(|o| o.bytes).sum();
    let counts = push_sample_data(&mut tb, seed, &plans, &tl, &outs_ok);
    // Annotations: every actor within range of the ego at each keyframe.
    for (si, plan) in plans.iter().enumerate() {
        push_annotations(&mut tb, seed, si, plan, &counts);
    }
    bytes += write_map(root, &mut tb, &plans, map_token)?;

    let vdir = root.join(&cfg.version_name);
    bytes += write_tables(&vdir, &tb)?;
    bytes += write_splits(&vdir, &tb, &weathers)?;
    let summary = SynthSummary {
        keyframes: cfg.scenes * m,
        scenes: cfg.scenes,
        sample_data: tb.sample_data.len(),
        files: tl.jobs.len()
            + if cfg.truth { m * cfg.scenes } else { 0 }
            + 14
            + crate::splits::SPLIT_NAMES.len(),
        bytes,
        version_dir: vdir,
        seconds: 0.0,
        conditions: weathers.iter().fold([0usize; 3], |mut acc, w| {
            acc[*w as usize] += 1;
            acc
        }),
    };
    write_marker(root, cfg)?;
    Ok(summary)
}

/// The tables that do not depend on the scenes: category, attribute, visibility, sensor.
fn push_fixed_tables(tb: &mut Tables, mounts: &[Mount]) {
    let cats = [
        ("vehicle.car", "Vehicle designed primarily for personal use, e.g. sedans, hatch-backs, wagons, vans, mini-vans, SUVs and jeeps."),
        ("vehicle.truck", "Vehicles primarily designed to haul cargo including pick-ups, lorrys, trucks and semi-tractors."),
        ("vehicle.bus.rigid", "Rigid bus."),
        ("human.pedestrian.adult", "Adult subcategory."),
    ];
    for (n, d) in cats {
        tb.category.push(Category {
            token: name_token("category", n),
            name: n.into(),
            description: d.into(),
        });
    }
    let attrs = [
        ("vehicle.moving", "Vehicle is moving."),
        ("vehicle.stopped", "Vehicle, with a driver/rider in/on it, is currently stationary but has an intent to move."),
        ("vehicle.parked", "Vehicle is stationary (usually for longer duration) with no immediate intent to move."),
        ("pedestrian.moving", "The human is moving."),
        ("pedestrian.standing", "The human is standing."),
    ];
    for (n, d) in attrs {
        tb.attribute.push(Attribute {
            token: name_token("attribute", n),
            name: n.into(),
            description: d.into(),
        });
    }
    for (i, (lvl, d)) in [
        ("v0-40", "visibility of whole object is between 0 and 40%"),
        ("v40-60", "visibility of whole object is between 40 and 60%"),
        ("v60-80", "visibility of whole object is between 60 and 80%"),
        (
            "v80-100",
            "visibility of whole object is between 80 and 100%",
        ),
    ]
    .iter()
    .enumerate()
    {
        tb.visibility.push(Visibility {
            token: (i + 1).to_string(),
            level: lvl.to_string(),
            description: d.to_string(),
        });
    }
    for mt in mounts {
        tb.sensor.push(Sensor {
            token: name_token("sensor", mt.channel),
            channel: mt.channel.into(),
            modality: mt.modality.into(),
        });
    }
}

/// Time of the first keyframe (s): after the lidar sweeps that precede it.
fn first_keyframe_t() -> f64 {
    0.1 + LIDAR_PAD as f64 * calib::LIDAR_PERIOD_S
}

/// Build every scene's world (in parallel) with its log name, keyframe times and sample tokens.
fn plan_scenes(seed: u64, m: usize, weathers: &[Weather]) -> Vec<ScenePlan> {
    let kf_t0 = first_keyframe_t();
    let duration = kf_t0 + (m as f64 - 1.0) * calib::KEYFRAME_PERIOD_S + 0.6;
    weathers
        .iter()
        .enumerate()
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|(i, &w)| {
            let world = World::build(seed, i, w, duration);
            let kf_t: Vec<f64> = (0..m)
                .map(|k| kf_t0 + k as f64 * calib::KEYFRAME_PERIOD_S)
                .collect();
            let sample_tokens = (0..m)
                .map(|k| token(seed, &[hash_str("sample"), i as u64, k as u64]))
                .collect();
            ScenePlan {
                world,
                logfile: format!(
                    "synth{:03}-2026-01-{:02}-{:02}-00-00+0000",
                    seed % 1000,
                    1 + i % 28,
                    i / 28 % 24
                ),
                kf_t,
                sample_tokens,
            }
        })
        .collect()
}

/// Every scene's table rows (log, scene, sample, calibrated_sensor) and frame timeline.
fn plan_frames(
    tb: &mut Tables,
    cfg: &SynthConfig,
    plans: &[ScenePlan],
    mounts: &[Mount],
) -> Timeline {
    let seed = cfg.seed;
    let radar_mounts: Vec<Mount> = calib::RADAR_CHANNELS
        .iter()
        .map(|c| calib::radar(c))
        .collect();
    let mut tl = Timeline::default();
    for (si, plan) in plans.iter().enumerate() {
        let mut jr = Rng::stream(seed, &[hash_str("timing"), si as u64]);
        push_scene_tables(tb, seed, si, plan, mounts);
        let ids = SceneIds { seed, si };
        tl.add_camera(&ids, plan, &mut jr, cfg);
        tl.add_lidar(&ids, plan, &mut jr, cfg.lidar_sweeps);
        for rm in &radar_mounts {
            tl.add_radar(&ids, plan, rm, &mut jr, cfg.radar_sweeps);
        }
    }
    tl
}

/// The log, scene, sample and calibrated_sensor rows of scene `si`.
fn push_scene_tables(tb: &mut Tables, seed: u64, si: usize, plan: &ScenePlan, mounts: &[Mount]) {
    let m = plan.sample_tokens.len();
    let log_token = token(seed, &[hash_str("log"), si as u64]);
    let scene_token = token(seed, &[hash_str("scene"), si as u64]);
    tb.log.push(Log {
        token: log_token.clone(),
        logfile: plan.logfile.clone(),
        vehicle: "synth".into(),
        date_captured: "2026-01-01".into(),
        location: "synth-city".into(),
    });
    tb.scene.push(Scene {
        token: scene_token.clone(),
        log_token,
        nbr_samples: m,
        first_sample_token: plan.sample_tokens[0].clone(),
        last_sample_token: plan.sample_tokens[m - 1].clone(),
        name: format!("synth-{si:04}"),
        description: plan.world.description.clone(),
    });
    for k in 0..m {
        tb.sample.push(Sample {
            token: plan.sample_tokens[k].clone(),
            timestamp: ts_us(si, plan.kf_t[k]),
            prev: if k > 0 {
                plan.sample_tokens[k - 1].clone()
            } else {
                String::new()
            },
            next: if k + 1 < m {
                plan.sample_tokens[k + 1].clone()
            } else {
                String::new()
            },
            scene_token: scene_token.clone(),
        });
    }
    for mt in mounts {
        tb.calibrated_sensor
            .push(calibrated_sensor_row(seed, si, mt));
    }
}

/// The calibrated_sensor row of one mount in scene `si`.
fn calibrated_sensor_row(seed: u64, si: usize, mt: &Mount) -> CalibratedSensor {
    let intr = if mt.modality == "camera" {
        vec![
            [calib::CAM_FX, 0.0, calib::CAM_CX],
            [0.0, calib::CAM_FY, calib::CAM_CY],
            [0.0, 0.0, 1.0],
        ]
    } else {
        Vec::new()
    };
    CalibratedSensor {
        token: token(
            seed,
            &[
                hash_str("calibrated_sensor"),
                si as u64,
                hash_str(mt.channel),
            ],
        ),
        sensor_token: name_token("sensor", mt.channel),
        translation: mt.translation,
        rotation: mt.rotation_wxyz,
        camera_intrinsic: intr,
    }
}

/// The sample_data token and the RNG salt of frame `j` of a channel of scene `si`.
struct SceneIds {
    seed: u64,
    si: usize,
}

impl SceneIds {
    /// sample_data token (also the ego_pose token) of frame `j` of channel `ch`.
    fn sd_token(&self, ch: &str, j: usize) -> String {
        token(
            self.seed,
            &[
                hash_str("sample_data"),
                self.si as u64,
                hash_str(ch),
                j as u64,
            ],
        )
    }

    /// RNG salt of frame `j` of channel `ch`.
    fn salt(&self, ch: &str, j: usize) -> u64 {
        crate::rng::hash_ids(
            self.seed,
            &[hash_str("frame"), self.si as u64, hash_str(ch), j as u64],
        )
    }
}

/// Index of the time in `times` nearest to `t` (the first on a tie).
fn nearest_index(times: &[f64], t: f64) -> usize {
    times
        .iter()
        .enumerate()
        .map(|(j, &tt)| (j, (tt - t).abs()))
        .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a })
        .0
}

/// One frame of a channel: its job and, for a keyframe, its sample index.
struct ChanRow {
    job: usize,
    kf: Option<usize>,
}

/// Every frame to render (one job per file) and the per-channel frame lists.
#[derive(Default)]
struct Timeline {
    jobs: Vec<Job>,
    /// Per (scene, channel) lists of (job index, is_keyframe sample index).
    chans: Vec<(usize, &'static str, Vec<ChanRow>)>,
}

impl Timeline {
    /// CAM_FRONT at the keyframes.
    fn add_camera(&mut self, ids: &SceneIds, plan: &ScenePlan, jr: &mut Rng, cfg: &SynthConfig) {
        let si = ids.si;
        let mut rows = Vec::new();
        for k in 0..plan.kf_t.len() {
            let t = plan.kf_t[k] + calib::CAM_OFFSET_S + jr.range(-0.002, 0.002);
            let tok = ids.sd_token(calib::CAM_FRONT, k);
            rows.push(ChanRow {
                job: self.jobs.len(),
                kf: Some(k),
            });
            self.jobs.push(Job {
                scene: si,
                kind: JobKind::Cam {
                    truth: cfg.truth.then(|| format!("{TRUTH_DIR}/{tok}.png")),
                    scale: cfg.camera_scale.max(1),
                    jpeg_420: cfg.jpeg_420,
                },
                t,
                filename: format!(
                    "samples/CAM_FRONT/{}__CAM_FRONT__{}.jpg",
                    plan.logfile,
                    ts_us(si, t)
                ),
                token: tok,
                salt: ids.salt(calib::CAM_FRONT, k),
            });
        }
        self.chans.push((si, calib::CAM_FRONT, rows));
    }

    /// LIDAR_TOP at 20 Hz, keyframes every 10th sweep; with `keep` = Some(K) only the keyframes
    /// and the K sweeps on each side of them (the others' jitter is still drawn, so the sweeps
    /// kept are those of the full world).
    fn add_lidar(&mut self, ids: &SceneIds, plan: &ScenePlan, jr: &mut Rng, keep: Option<usize>) {
        let si = ids.si;
        let m = plan.kf_t.len();
        let kf_t0 = first_keyframe_t();
        let per = (calib::KEYFRAME_PERIOD_S / calib::LIDAR_PERIOD_S).round() as usize;
        let n_lidar = (m - 1) * per + 1 + 2 * LIDAR_PAD;
        let mut rows = Vec::new();
        for j in 0..n_lidar {
            let kf = if j >= LIDAR_PAD && (j - LIDAR_PAD).is_multiple_of(per) {
                Some((j - LIDAR_PAD) / per)
            } else {
                None
            };
            let t = match kf {
                Some(k) => plan.kf_t[k],
                None => {
                    kf_t0
                        + (j as f64 - LIDAR_PAD as f64) * calib::LIDAR_PERIOD_S
                        + jr.range(-0.0008, 0.0008)
                }
            };
            if let Some(k) = keep {
                // Sweeps from the nearest keyframe sweep (index LIDAR_PAD + i·per).
                let rel = j as i64 - LIDAR_PAD as i64;
                let nearest = rel.clamp(0, ((m - 1) * per) as i64);
                let off = (rel - nearest).unsigned_abs() as usize;
                let inside = rel.rem_euclid(per as i64) as usize;
                let dist = if rel == nearest {
                    inside.min(per - inside)
                } else {
                    off
                };
                if dist > k {
                    continue;
                }
            }
            let folder = if kf.is_some() { "samples" } else { "sweeps" };
            rows.push(ChanRow {
                job: self.jobs.len(),
                kf,
            });
            self.jobs.push(Job {
                scene: si,
                kind: JobKind::Lidar,
                t,
                filename: format!(
                    "{folder}/LIDAR_TOP/{}__LIDAR_TOP__{}.pcd.bin",
                    plan.logfile,
                    ts_us(si, t)
                ),
                token: ids.sd_token(calib::LIDAR_TOP, j),
                salt: ids.salt(calib::LIDAR_TOP, j),
            });
        }
        self.chans.push((si, calib::LIDAR_TOP, rows));
    }

    /// A radar at ≈13 Hz with its own phase; the sweep nearest each keyframe is the keyframe.
    /// With `keep` = Some(N), only the N sweeps up to each keyframe sweep are written.
    fn add_radar(
        &mut self,
        ids: &SceneIds,
        plan: &ScenePlan,
        rm: &Mount,
        jr: &mut Rng,
        keep: Option<usize>,
    ) {
        let si = ids.si;
        let (times, kf_of) = radar_times(plan, jr);
        let mut rows = Vec::new();
        // For each sweep, how many sweeps on the next keyframe sweep is.
        let mut to_next = vec![usize::MAX; times.len()];
        let mut next: Option<usize> = None;
        for j in (0..times.len()).rev() {
            if kf_of[j].is_some() {
                next = Some(j);
            }
            if let Some(n) = next {
                to_next[j] = n - j;
            }
        }
        for (j, &t) in times.iter().enumerate() {
            if keep.is_some_and(|n| to_next[j] >= n.max(1)) {
                continue;
            }
            let folder = if kf_of[j].is_some() {
                "samples"
            } else {
                "sweeps"
            };
            rows.push(ChanRow {
                job: self.jobs.len(),
                kf: kf_of[j],
            });
            self.jobs.push(Job {
                scene: si,
                kind: JobKind::Radar { mount: *rm },
                t,
                filename: format!(
                    "{folder}/{}/{}__{}__{}.pcd",
                    rm.channel,
                    plan.logfile,
                    rm.channel,
                    ts_us(si, t)
                ),
                token: ids.sd_token(rm.channel, j),
                salt: ids.salt(rm.channel, j),
            });
        }
        self.chans.push((si, rm.channel, rows));
    }
}

/// Sweep times of one radar (random phase and jitter) and the keyframe index of each sweep.
fn radar_times(plan: &ScenePlan, jr: &mut Rng) -> (Vec<f64>, Vec<Option<usize>>) {
    let m = plan.kf_t.len();
    let phase = jr.range(0.0, calib::RADAR_PERIOD_S);
    let t_first = plan.kf_t[0] - 5.0 * calib::RADAR_PERIOD_S + phase - calib::RADAR_PERIOD_S / 2.0;
    let t_last = plan.kf_t[m - 1] + calib::RADAR_PERIOD_S / 2.0;
    let mut times = Vec::new();
    let mut t = t_first;
    while t <= t_last {
        times.push(t + jr.range(-0.001, 0.001));
        t += calib::RADAR_PERIOD_S;
    }
    let mut kf_of = vec![None; times.len()];
    for k in 0..m {
        let jbest = nearest_index(&times, plan.kf_t[k]);
        kf_of[jbest] = Some(k);
    }
    (times, kf_of)
}

/// The dataroot's folders: samples/ and sweeps/ per channel, truth/, maps/, the version.
fn create_dirs(root: &Path, mounts: &[Mount], version_name: &str) -> Result<(), SynthError> {
    for d in ["samples", "sweeps"] {
        for mt in mounts {
            let p = root.join(d).join(mt.channel);
            std::fs::create_dir_all(&p).map_err(io_err(&p))?;
        }
    }
    for d in [TRUTH_DIR, "maps", version_name] {
        let p = root.join(d);
        std::fs::create_dir_all(&p).map_err(io_err(&p))?;
    }
    Ok(())
}

/// Render and write every frame in parallel; each frame has its own RNG stream.
fn render_frames(
    root: &Path,
    cfg: &SynthConfig,
    jobs: &[Job],
    plans: &[ScenePlan],
    progress: &depthsense_progress::Progress,
) -> Result<Vec<JobOut>, SynthError> {
    progress.set_length(jobs.len() as u64);
    progress.println(format!(
        "{} scenes, {} frames (keyframes and sweeps of every sensor) to render",
        plans.len(),
        jobs.len()
    ));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(cfg.jobs)
        .build()
        .map_err(|source| SynthError::ThreadPool {
            jobs: cfg.jobs,
            source,
        })?;
    let outs: Vec<Result<JobOut, SynthError>> = pool.install(|| {
        jobs.par_iter()
            .map(|job| {
                let r = run_job(root, &plans[job.scene].world, job);
                progress.inc(1);
                r
            })
            .collect()
    });
    let mut outs_ok = Vec::with_capacity(outs.len());
    for o in outs {
        outs_ok.push(o?);
    }
    Ok(outs_ok)
}

/// Points per object at each (scene, keyframe index).
type ObjCounts = BTreeMap<(usize, usize), BTreeMap<u32, u32>>;

/// Lidar and radar points per object at each keyframe (the annotations' point counts).
#[derive(Default)]
struct KeyframeCounts {
    lidar: ObjCounts,
    radar: ObjCounts,
}

impl KeyframeCounts {
    /// Add a keyframe's points per object: the lidar sweep's, or summed over the radars.
    fn add(&mut self, si: usize, k: usize, kind: &JobKind, counts: &[(u32, u32)]) {
        match kind {
            JobKind::Lidar => {
                self.lidar
                    .entry((si, k))
                    .or_default()
                    .extend(counts.iter().copied());
            }
            JobKind::Radar { .. } => {
                let e = self.radar.entry((si, k)).or_default();
                for &(o, c) in counts {
                    *e.entry(o).or_default() += c;
                }
            }
            _ => {}
        }
    }

    /// (lidar, radar) points on actor `ai` at keyframe `k` of scene `si`.
    fn of(&self, si: usize, k: usize, ai: usize) -> (u32, u32) {
        let get = |c: &ObjCounts| {
            c.get(&(si, k))
                .and_then(|c| c.get(&(ai as u32)))
                .copied()
                .unwrap_or(0)
        };
        (get(&self.lidar), get(&self.radar))
    }
}

/// sample_data and ego_pose rows, channel by channel, with prev/next chains; returns the
/// keyframes' points per object.
fn push_sample_data(
    tb: &mut Tables,
    seed: u64,
    plans: &[ScenePlan],
    tl: &Timeline,
    outs_ok: &[JobOut],
) -> KeyframeCounts {
    let mut counts = KeyframeCounts::default();
    for (si, ch, rows) in &tl.chans {
        let plan = &plans[*si];
        let cs_token = token(
            seed,
            &[hash_str("calibrated_sensor"), *si as u64, hash_str(ch)],
        );
        for (r, row) in rows.iter().enumerate() {
            let job = &tl.jobs[row.job];
            let (ep, eq) = plan.world.ego_pose(job.t);
            let ts = ts_us(*si, job.t);
            tb.ego_pose.push(EgoPose {
                token: job.token.clone(),
                timestamp: ts,
                rotation: q_wxyz(eq),
                translation: [ep.x, ep.y, ep.z],
            });
            let chain_token = |i: usize| tl.jobs[rows[i].job].token.clone();
            let prev = if r > 0 {
                chain_token(r - 1)
            } else {
                String::new()
            };
            let next = if r + 1 < rows.len() {
                chain_token(r + 1)
            } else {
                String::new()
            };
            tb.sample_data.push(sample_data_row(
                plan, job, row.kf, &cs_token, ts, prev, next,
            ));
            if let Some(k) = row.kf {
                counts.add(*si, k, &job.kind, &outs_ok[row.job].counts);
            }
        }
    }
    counts
}

/// The sample_data row of one frame.
fn sample_data_row(
    plan: &ScenePlan,
    job: &Job,
    kf: Option<usize>,
    cs_token: &str,
    ts: i64,
    prev: String,
    next: String,
) -> SampleData {
    // Sweeps belong to the nearest keyframe's sample.
    let sample_k = kf.unwrap_or_else(|| nearest_index(&plan.kf_t, job.t));
    let (fileformat, w, h) = match job.kind {
        JobKind::Cam { .. } => ("jpg", IMG_W, IMG_H),
        _ => ("pcd", 0, 0),
    };
    SampleData {
        token: job.token.clone(),
        sample_token: plan.sample_tokens[sample_k].clone(),
        ego_pose_token: job.token.clone(),
        calibrated_sensor_token: cs_token.to_string(),
        timestamp: ts,
        fileformat: fileformat.into(),
        is_key_frame: kf.is_some(),
        height: h,
        width: w,
        filename: job.filename.clone(),
        prev,
        next,
    }
}

/// The sample_annotation and instance rows of scene `si`: every actor within range of the
/// ego at each keyframe, chained per actor.
fn push_annotations(
    tb: &mut Tables,
    seed: u64,
    si: usize,
    plan: &ScenePlan,
    counts: &KeyframeCounts,
) {
    let w = &plan.world;
    let mut per_actor: BTreeMap<usize, Vec<(usize, SampleAnnotation)>> = BTreeMap::new();
    for k in 0..plan.kf_t.len() {
        let t = plan.kf_t[k];
        let (ep, _) = w.ego_pose(t);
        for ai in 0..w.actors.len() {
            let st = w.actor_state(ai, t);
            if (st.pos - DVec2::new(ep.x, ep.y)).length() > ANNOTATE_RANGE_M
                || w.actor_hidden(ai, &st, t)
            {
                continue;
            }
            let ann = annotation(seed, si, plan, k, ai, &st, counts.of(si, k, ai));
            per_actor.entry(ai).or_default().push((k, ann));
        }
    }
    for (ai, mut anns) in per_actor {
        let n = anns.len();
        for i in 0..n {
            if i > 0 {
                anns[i].1.prev = anns[i - 1].1.token.clone();
            }
            if i + 1 < n {
                anns[i].1.next = anns[i + 1].1.token.clone();
            }
        }
        tb.instance.push(Instance {
            token: token(seed, &[hash_str("instance"), si as u64, ai as u64]),
            category_token: name_token("category", w.actors[ai].kind.category()),
            nbr_annotations: n,
            first_annotation_token: anns[0].1.token.clone(),
            last_annotation_token: anns[n - 1].1.token.clone(),
        });
        tb.sample_annotation.extend(anns.into_iter().map(|a| a.1));
    }
}

/// The (unchained) annotation of actor `ai` in state `st` at keyframe `k`, with its
/// (lidar, radar) point counts `(nl, nr)`.
fn annotation(
    seed: u64,
    si: usize,
    plan: &ScenePlan,
    k: usize,
    ai: usize,
    st: &ActorState,
    (nl, nr): (u32, u32),
) -> SampleAnnotation {
    let a = &plan.world.actors[ai];
    let speed = st.vel.length();
    let attr = match (a.kind, a.motion) {
        (ActorKind::Pedestrian, _) if speed > 0.3 => "pedestrian.moving",
        (ActorKind::Pedestrian, _) => "pedestrian.standing",
        (_, Motion::Parked { .. }) => "vehicle.parked",
        _ if speed > 0.3 => "vehicle.moving",
        _ => "vehicle.stopped",
    };
    let vis = match nl {
        0 => "1",
        1..=9 => "2",
        10..=49 => "3",
        _ => "4",
    };
    SampleAnnotation {
        token: token(
            seed,
            &[
                hash_str("sample_annotation"),
                si as u64,
                ai as u64,
                k as u64,
            ],
        ),
        sample_token: plan.sample_tokens[k].clone(),
        instance_token: token(seed, &[hash_str("instance"), si as u64, ai as u64]),
        visibility_token: vis.into(),
        attribute_tokens: vec![name_token("attribute", attr)],
        translation: [st.pos.x, st.pos.y, a.size.z / 2.0],
        size: [a.size.y, a.size.x, a.size.z],
        rotation: q_wxyz(DQuat::from_rotation_z(st.yaw)),
        prev: String::new(),
        next: String::new(),
        num_lidar_pts: nl,
        num_radar_pts: nr,
        velocity: [st.vel.x, st.vel.y, 0.0],
    }
}

/// Semantic-prior map (roads and sidewalks) of the synthetic city: writes the PNG, adds the
/// map row and returns the bytes written.
fn write_map(
    root: &Path,
    tb: &mut Tables,
    plans: &[ScenePlan],
    map_token: String,
) -> Result<u64, SynthError> {
    let map_file = format!("maps/{map_token}.png");
    let map_bytes = render_map(plans)?;
    let map_path = root.join(&map_file);
    std::fs::write(&map_path, &map_bytes).map_err(io_err(&map_path))?;
    tb.map.push(MapRow {
        token: map_token,
        log_tokens: tb.log.iter().map(|l| l.token.clone()).collect(),
        category: "semantic_prior".into(),
        filename: map_file,
    });
    Ok(map_bytes.len() as u64)
}

/// Write the 13 tables to `<version>/<table>.json`; returns the bytes written.
fn write_tables(vdir: &Path, tb: &Tables) -> Result<u64, SynthError> {
    let mut bytes = 0;
    for (stem, json) in tb
        .to_json()
        .map_err(|source| SynthError::Tables { source })?
    {
        let p = vdir.join(format!("{stem}.json"));
        bytes += json.len() as u64;
        std::fs::write(&p, json).map_err(io_err(&p))?;
    }
    Ok(bytes)
}

/// Train / val / test scene lists (by condition, never by content; see `splits`); returns
/// the bytes written.
fn write_splits(vdir: &Path, tb: &Tables, weathers: &[Weather]) -> Result<u64, SynthError> {
    let mut bytes = 0;
    let scene_splits = crate::splits::assign_splits(weathers);
    let sdir = vdir.join(crate::splits::SPLITS_DIR);
    std::fs::create_dir_all(&sdir).map_err(io_err(&sdir))?;
    for name in crate::splits::SPLIT_NAMES {
        let mut text = String::new();
        for (scene, sp) in tb.scene.iter().zip(&scene_splits) {
            if sp.name() == name {
                text.push_str(&scene.token);
                text.push('\n');
            }
        }
        let p = sdir.join(crate::splits::split_file_name(name));
        bytes += text.len() as u64;
        std::fs::write(&p, text).map_err(io_err(&p))?;
    }
    Ok(bytes)
}

/// The marker file at the dataroot (the configuration).
fn write_marker(root: &Path, cfg: &SynthConfig) -> Result<(), SynthError> {
    let mut marker = serde_json::json!({
        "generator": "depthsense synth",
        "version_name": cfg.version_name,
        "seed": cfg.seed,
        "scenes": cfg.scenes,
        "keyframes_per_scene": cfg.keyframes_per_scene,
        "conditions": cfg.conditions.iter().map(|(w, p)| (format!("{w:?}").to_lowercase(), *p)).collect::<Vec<_>>(),
        "map_resolution_m": MAP_RES_M,
    });
    // What a leaner world left out (absent for a full world, whose marker is unchanged).
    if cfg.camera_scale > 1 {
        marker["camera_scale"] = serde_json::json!(cfg.camera_scale);
    }
    if let Some(k) = cfg.lidar_sweeps {
        marker["lidar_sweeps"] = serde_json::json!(k);
    }
    if !cfg.truth {
        marker["truth"] = serde_json::json!(false);
    }
    if let Some(n) = cfg.radar_sweeps {
        marker["radar_sweeps"] = serde_json::json!(n);
    }
    if cfg.jpeg_420 {
        marker["jpeg"] = serde_json::json!("4:2:0");
    }
    let p = root.join(MARKER_FILE);
    std::fs::write(
        &p,
        serde_json::to_vec_pretty(&marker).map_err(|source| SynthError::Marker { source })?,
    )
    .map_err(io_err(&p))
}

fn run_job(root: &Path, world: &World, job: &Job) -> Result<JobOut, SynthError> {
    let path = root.join(&job.filename);
    match &job.kind {
        JobKind::Cam {
            truth,
            scale,
            jpeg_420,
        } => {
            let f = camera::render_scaled(world, job.t, job.salt, *scale);
            let jpg = encode_jpeg(&f.rgb, *jpeg_420).map_err(|source| SynthError::CameraJpeg {
                file: PathBuf::from(&job.filename),
                source,
            })?;
            std::fs::write(&path, &jpg).map_err(io_err(&path))?;
            let mut bytes = jpg.len() as u64;
            if let Some(truth) = truth {
                let png = encode_png(&DepthMap {
                    width: IMG_W,
                    height: IMG_H,
                    depth_m: f.depth_m,
                })
                .map_err(|source| SynthError::TruthPng {
                    file: PathBuf::from(truth),
                    source,
                })?;
                let tp = root.join(truth);
                std::fs::write(&tp, &png).map_err(io_err(&tp))?;
                bytes += png.len() as u64;
            }
            Ok(JobOut {
                bytes,
                counts: Vec::new(),
            })
        }
        JobKind::Lidar => {
            let s = lidar::scan(world, job.t, job.salt);
            let bytes = encode_lidar_pcd_bin(&s.points);
            std::fs::write(&path, &bytes).map_err(io_err(&path))?;
            Ok(JobOut {
                bytes: bytes.len() as u64,
                counts: count_objs(s.objs.iter().copied()),
            })
        }
        JobKind::Radar { mount } => {
            let s = radar::scan(world, mount, job.t, job.salt);
            let bytes = encode_radar_pcd_binary(&s.points);
            std::fs::write(&path, &bytes).map_err(io_err(&path))?;
            let objs = s.origins.iter().filter_map(|o| match o {
                radar::Origin::Surface { obj } | radar::Origin::Ghost { obj } => Some(*obj),
                radar::Origin::Clutter => None,
            });
            Ok(JobOut {
                bytes: bytes.len() as u64,
                counts: count_objs(objs),
            })
        }
    }
}

/// CAM_FRONT as JPEG, quality 90: 4:4:4 by the `image` crate, or 4:2:0 (as nuScenes' images)
/// by `jpeg-encoder`.
fn encode_jpeg(rgb: &[u8], jpeg_420: bool) -> Result<Vec<u8>, JpegError> {
    let mut jpg = Vec::with_capacity(400_000);
    if jpeg_420 {
        let mut e = jpeg_encoder::Encoder::new(&mut jpg, 90);
        e.set_sampling_factor(jpeg_encoder::SamplingFactor::R_4_2_0);
        e.encode(
            rgb,
            IMG_W as u16,
            IMG_H as u16,
            jpeg_encoder::ColorType::Rgb,
        )?;
    } else {
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpg, 90).encode(
            rgb,
            IMG_W,
            IMG_H,
            image::ExtendedColorType::Rgb8,
        )?;
    }
    Ok(jpg)
}

fn count_objs(it: impl Iterator<Item = u32>) -> Vec<(u32, u32)> {
    let mut m: BTreeMap<u32, u32> = BTreeMap::new();
    for o in it {
        if o < STATIC_OBJ_BASE {
            *m.entry(o).or_default() += 1;
        }
    }
    m.into_iter().collect()
}

/// 8-bit PNG of the city at [`MAP_RES_M`]: 255 on roads and sidewalks. Row 0 is the north
/// edge (the devkit's MapMask flips y).
fn render_map(plans: &[ScenePlan]) -> Result<Vec<u8>, SynthError> {
    let n = plans.len().max(1);
    let tiles_x = n.min(8);
    let tiles_y = n.div_ceil(8);
    let wpx = (1000.0 * tiles_x as f64 / MAP_RES_M) as u32 + (1000.0 / MAP_RES_M) as u32;
    let hpx = (1000.0 * tiles_y as f64 / MAP_RES_M) as u32 + (1000.0 / MAP_RES_M) as u32;
    let mut img = vec![0u8; wpx as usize * hpx as usize];
    for p in plans {
        // Pixel bounds of this scene's roads.
        let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for s in &p.world.segs {
            for q in [s.a, s.a + s.dir * s.len] {
                lo = lo.min(q - DVec2::splat(s.hw + s.sw + 1.0));
                hi = hi.max(q + DVec2::splat(s.hw + s.sw + 1.0));
            }
        }
        let x0 = (lo.x / MAP_RES_M).floor().max(0.0) as u32;
        let y0 = (lo.y / MAP_RES_M).floor().max(0.0) as u32;
        let x1 = ((hi.x / MAP_RES_M).ceil().max(0.0) as u32).min(wpx);
        let y1 = ((hi.y / MAP_RES_M).ceil().max(0.0) as u32).min(hpx);
        for yy in y0..y1 {
            for xx in x0..x1 {
                let gx = (xx as f64 + 0.5) * MAP_RES_M;
                let gy = (yy as f64 + 0.5) * MAP_RES_M;
                let row = hpx - 1 - yy;
                let k = p.world.ground_kind(DVec2::new(gx, gy));
                if k != Ground::Verge {
                    img[row as usize * wpx as usize + xx as usize] = 255;
                }
            }
        }
    }
    let buf = image::GrayImage::from_raw(wpx, hpx, img).ok_or(SynthError::MapBuffer {
        width: wpx,
        height: hpx,
    })?;
    let mut out = std::io::Cursor::new(Vec::new());
    buf.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|source| SynthError::MapPng { source })?;
    Ok(out.into_inner())
}

/// Single-thread time per frame of each stage (milliseconds), measured on a day scene.
#[derive(Debug, Clone, serde::Serialize)]
pub struct StageTimes {
    pub camera_render_ms: f64,
    pub camera_jpeg_ms: f64,
    pub truth_png_ms: f64,
    pub lidar_sweep_ms: f64,
    pub lidar_points_per_sweep: usize,
    pub radar_sweep_ms: f64,
    pub radar_points_per_sweep: f64,
    pub frames: usize,
}

/// Time each stage on `frames` frames of scene 0 (single thread).
pub fn profile_stages(seed: u64, frames: usize) -> Result<StageTimes, SynthError> {
    let frames = frames.max(1);
    let world = World::build(seed, 0, Weather::Day, 2.0 + frames as f64);
    let ms = |t: Instant| t.elapsed().as_secs_f64() * 1e3 / frames as f64;
    let t = Instant::now();
    let mut f = camera::render(&world, 1.0, 0);
    for k in 1..frames {
        f = camera::render(&world, 1.0 + k as f64, k as u64);
    }
    let camera_render_ms = ms(t);
    let t = Instant::now();
    for _ in 0..frames {
        let mut jpg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpg, 90)
            .encode(&f.rgb, IMG_W, IMG_H, image::ExtendedColorType::Rgb8)
            .map_err(|source| SynthError::ProfileJpeg { source })?;
    }
    let camera_jpeg_ms = ms(t);
    let dm = DepthMap {
        width: IMG_W,
        height: IMG_H,
        depth_m: f.depth_m,
    };
    let t = Instant::now();
    for _ in 0..frames {
        encode_png(&dm).map_err(|source| SynthError::ProfilePng { source })?;
    }
    let truth_png_ms = ms(t);
    let t = Instant::now();
    let mut npts = 0;
    for k in 0..frames {
        npts = lidar::scan(&world, 1.0 + k as f64, k as u64).points.len();
    }
    let lidar_sweep_ms = ms(t);
    let m = calib::radar(calib::RADAR_FRONT);
    let t = Instant::now();
    let mut rp = 0usize;
    for k in 0..frames {
        rp += radar::scan(&world, &m, 1.0 + k as f64, k as u64)
            .points
            .len();
    }
    let radar_sweep_ms = ms(t);
    Ok(StageTimes {
        camera_render_ms,
        camera_jpeg_ms,
        truth_png_ms,
        lidar_sweep_ms,
        lidar_points_per_sweep: npts,
        radar_sweep_ms,
        radar_points_per_sweep: rp as f64 / frames as f64,
        frames,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conditions_are_allocated_in_proportion() {
        let mix = [
            (Weather::Day, 0.5),
            (Weather::Night, 0.25),
            (Weather::Rain, 0.25),
        ];
        let a = allocate_conditions(8, &mix);
        let count = |w| a.iter().filter(|x| **x == w).count();
        assert_eq!(
            (
                count(Weather::Day),
                count(Weather::Night),
                count(Weather::Rain)
            ),
            (4, 2, 2)
        );
        // Every condition with weight appears as soon as there are enough scenes.
        let b = allocate_conditions(
            3,
            &[
                (Weather::Day, 1.0),
                (Weather::Night, 1.0),
                (Weather::Rain, 1.0),
            ],
        );
        assert_eq!(b, vec![Weather::Day, Weather::Night, Weather::Rain]);
        let c = allocate_conditions(5, &[(Weather::Day, 0.0), (Weather::Rain, 2.0)]);
        assert!(c.iter().all(|w| *w == Weather::Rain));
    }

    #[test]
    fn parse_condition_mix() {
        let m = SynthConfig::parse_conditions("day=0.5, night:0.3,rain").unwrap();
        assert_eq!(
            m,
            vec![
                (Weather::Day, 0.5),
                (Weather::Night, 0.3),
                (Weather::Rain, 1.0)
            ]
        );
        assert!(SynthConfig::parse_conditions("fog").is_err());
        assert!(SynthConfig::parse_conditions("day=-1").is_err());
        assert!(SynthConfig::parse_conditions("day=0").is_err());
        assert!(SynthConfig::parse_conditions("").is_err());
        assert!(SynthConfig::default().validate().is_ok());
        assert!(SynthConfig {
            scenes: 0,
            ..SynthConfig::default()
        }
        .validate()
        .is_err());
        assert!(SynthConfig {
            version_name: "../x".into(),
            ..SynthConfig::default()
        }
        .validate()
        .is_err());
        let d = SynthConfig::demo();
        assert!(d.scenes * d.keyframes_per_scene >= 60);
    }
}
