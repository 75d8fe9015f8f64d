//! Radar statistics of the synthetic RADAR_FRONT against the real one.
//!
//! `radar_stats [SCENES] [KEYFRAMES] [SEED]` builds the worlds of the demo configuration and
//! scans RADAR_FRONT at the keyframe times (no files written: fast); with `--real DIR` it reads
//! the real files of DIR (e.g. `../shared/fixtures/radar-front-mini`); with `--root DATAROOT`
//! it reads the RADAR_FRONT keyframe files of a generated world.
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

use depthsense_nuscenes::pcd::RadarPoint;
use depthsense_synth::radar_stats::radar_stats;
use depthsense_synth::{calib, generate::allocate_conditions, radar, world::World, SynthConfig};

/// Upper edges (degrees) of the first seven kept-azimuth bins; the eighth is open-ended.
const AZ_BIN_EDGES_DEG: [f64; 7] = [5.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0];

/// Prints the statistics of the real RADAR_FRONT `.pcd` files of `dir`, read in name order.
fn print_real_stats(dir: &Path) {
    let mut names: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "pcd"))
        .collect();
    names.sort();
    let files: Vec<_> = names
        .iter()
        .map(|p| depthsense_nuscenes::pcd::read_radar_pcd(p).unwrap().points)
        .collect();
    println!("real: {}", radar_stats(&files));
}

/// Prints the statistics of the RADAR_FRONT keyframe files of the generated world at `root`.
fn print_root_stats(root: &Path) {
    let nu = depthsense_nuscenes::NuScenes::load(root, "v1.0-synth").unwrap();
    let files: Vec<_> = nu
        .sample
        .iter()
        .map(|s| {
            let sd = nu.keyframe(s.token, "RADAR_FRONT").unwrap();
            depthsense_nuscenes::pcd::read_radar_pcd(&nu.path_of(sd))
                .unwrap()
                .points
        })
        .collect();
    println!("files: {}", radar_stats(&files));
}

/// The demo configuration at 10 scenes × 8 keyframes, overridden by the optional positional
/// arguments `[SCENES] [KEYFRAMES] [SEED]` (`args[1..=3]`).
fn synth_config_from_args(args: &[String]) -> SynthConfig {
    let mut cfg = SynthConfig::demo();
    cfg.scenes = 10;
    cfg.keyframes_per_scene = 8;
    if let Some(s) = args.get(1) {
        cfg.scenes = s.parse().unwrap();
    }
    if let Some(s) = args.get(2) {
        cfg.keyframes_per_scene = s.parse().unwrap();
    }
    if let Some(s) = args.get(3) {
        cfg.seed = s.parse().unwrap();
    }
    cfg
}

/// Label of where a radar point of `world` comes from: the actor kind or static surface of
/// the reflecting object, `ghost` or `clutter`.
fn origin_label(world: &World, origin: &radar::Origin) -> String {
    match origin {
        radar::Origin::Surface { obj } if *obj < depthsense_synth::world::STATIC_OBJ_BASE => {
            format!("{:?}", world.actors[*obj as usize].kind)
        }
        radar::Origin::Surface { obj } => format!(
            "{:?}",
            world
                .statics
                .iter()
                .find(|q| q.obj == *obj)
                .map(|q| q.surface)
        ),
        radar::Origin::Ghost { .. } => "ghost".into(),
        radar::Origin::Clutter => "clutter".into(),
    }
}

/// Horizontal range (m) of a radar point in the sensor frame, `hypot(x, y)`.
fn range_m(p: &RadarPoint) -> f64 {
    (p.x as f64).hypot(p.y as f64)
}

/// Absolute azimuth (degrees) of a radar point in the sensor frame.
fn abs_azimuth_deg(p: &RadarPoint) -> f64 {
    (p.y as f64).atan2(p.x as f64).to_degrees().abs()
}

/// Scans RADAR_FRONT at the keyframe times of every world of `cfg`; returns the sweeps (one
/// per keyframe) and the ranges (m) of all their points keyed by origin label.
fn scan_synthetic(cfg: &SynthConfig) -> (Vec<Vec<RadarPoint>>, BTreeMap<String, Vec<f64>>) {
    let ws = allocate_conditions(cfg.scenes, &cfg.conditions);
    let m = calib::radar(calib::RADAR_FRONT);
    let kf_t0_s = 0.1 + 5.0 * calib::LIDAR_PERIOD_S;
    let dur_s = kf_t0_s + (cfg.keyframes_per_scene as f64 - 1.0) * calib::KEYFRAME_PERIOD_S + 0.6;
    let mut files = Vec::new();
    let mut range_m_by_origin: BTreeMap<String, Vec<f64>> = Default::default();
    for (i, w) in ws.iter().enumerate() {
        let world = World::build(cfg.seed, i, *w, dur_s);
        for k in 0..cfg.keyframes_per_scene {
            let tk_s = kf_t0_s + k as f64 * calib::KEYFRAME_PERIOD_S;
            let sw = radar::scan(&world, &m, tk_s, (i * 1000 + k) as u64);
            for (p, o) in sw.points.iter().zip(&sw.origins) {
                range_m_by_origin
                    .entry(origin_label(&world, o))
                    .or_default()
                    .push(range_m(p));
            }
            files.push(sw.points);
        }
    }
    (files, range_m_by_origin)
}

/// Prints, per origin label, its share of all points and its median range (m).
fn print_origin_shares(range_m_by_origin: &mut BTreeMap<String, Vec<f64>>) {
    let tot: usize = range_m_by_origin.values().map(|v| v.len()).sum();
    for (k, v) in range_m_by_origin {
        v.sort_by(f64::total_cmp);
        println!(
            "{k:>24}: {:5.1} %  median range {:.1}",
            100.0 * v.len() as f64 / tot as f64,
            v[v.len() / 2]
        );
    }
}

/// Fractions of the kept points of `files` in the absolute-azimuth bins 0-5-10-20-30-40-50-60-
/// degrees, formatted with three decimals.
fn kept_azimuth_bin_fractions(files: &[Vec<RadarPoint>]) -> Vec<String> {
    let mut az = [0usize; 8];
    let mut n = 0;
    for f in files {
        for p in f.iter().filter(|p| p.passes_default_filters()) {
            let a_deg = abs_azimuth_deg(p);
            let i = AZ_BIN_EDGES_DEG
                .iter()
                .position(|edge| a_deg < *edge)
                .unwrap_or(AZ_BIN_EDGES_DEG.len());
            az[i] += 1;
            n += 1;
        }
    }
    az.iter()
        .map(|c| format!("{:.3}", *c as f64 / n as f64))
        .collect()
}

/// Prints the count, median and p90 range (m) of the kept points of `files` within 10° of
/// boresight.
fn print_near_boresight_ranges(files: &[Vec<RadarPoint>]) {
    let mut r10_m: Vec<f64> = files
        .iter()
        .flat_map(|f| {
            f.iter()
                .filter(|p| p.passes_default_filters() && abs_azimuth_deg(p) < 10.0)
                .map(range_m)
        })
        .collect();
    r10_m.sort_by(f64::total_cmp);
    println!(
        "kept |az|<10: n {} median range {:.1} p90 {:.1}",
        r10_m.len(),
        r10_m[r10_m.len() / 2],
        r10_m[r10_m.len() * 9 / 10]
    );
}

/// Scans the synthetic worlds of `cfg` and prints the per-origin, azimuth and summary
/// statistics.
fn print_synthetic_stats(cfg: &SynthConfig) {
    let t = Instant::now();
    let (files, mut range_m_by_origin) = scan_synthetic(cfg);
    print_origin_shares(&mut range_m_by_origin);
    let az = kept_azimuth_bin_fractions(&files);
    print_near_boresight_ranges(&files);
    println!("kept |az| bins 0-5-10-20-30-40-50-60-: {}", az.join(" "));
    println!(
        "synthetic ({} scenes × {} keyframes, seed {}, {:.1} s): {}",
        cfg.scenes,
        cfg.keyframes_per_scene,
        cfg.seed,
        t.elapsed().as_secs_f64(),
        radar_stats(&files)
    );
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    match a.get(1).map(|s| s.as_str()) {
        Some("--real") => print_real_stats(Path::new(&a[2])),
        Some("--root") => print_root_stats(Path::new(&a[2])),
        _ => print_synthetic_stats(&synth_config_from_args(&a)),
    }
}
