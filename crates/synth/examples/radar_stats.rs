//! Radar statistics of the synthetic RADAR_FRONT against the real one.
//!
//! `radar_stats [SCENES] [KEYFRAMES] [SEED]` builds the worlds of the demo configuration and
//! scans RADAR_FRONT at the keyframe times (no files written: fast); with `--real DIR` it reads
//! the real files of DIR (e.g. `../shared/fixtures/radar-front-mini`); with `--root DATAROOT`
//! it reads the RADAR_FRONT keyframe files of a generated world.
use depthsense_synth::radar_stats::radar_stats;
use depthsense_synth::{calib, generate::allocate_conditions, radar, world::World, SynthConfig};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    if a.get(1).map(|s| s.as_str()) == Some("--real") {
        let dir = std::path::PathBuf::from(&a[2]);
        let mut files = Vec::new();
        let mut names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "pcd"))
            .collect();
        names.sort();
        for p in names {
            files.push(depthsense_nuscenes::pcd::read_radar_pcd(&p).unwrap().points);
        }
        println!("real: {}", radar_stats(&files));
        return;
    }
    if a.get(1).map(|s| s.as_str()) == Some("--root") {
        let root = std::path::PathBuf::from(&a[2]);
        let nu = depthsense_nuscenes::NuScenes::load(&root, "v1.0-synth").unwrap();
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
        return;
    }
    let mut cfg = SynthConfig::demo();
    cfg.scenes = 10;
    cfg.keyframes_per_scene = 8;
    if let Some(s) = a.get(1) {
        cfg.scenes = s.parse().unwrap();
    }
    if let Some(s) = a.get(2) {
        cfg.keyframes_per_scene = s.parse().unwrap();
    }
    if let Some(s) = a.get(3) {
        cfg.seed = s.parse().unwrap();
    }
    let ws = allocate_conditions(cfg.scenes, &cfg.conditions);
    let m = calib::radar(calib::RADAR_FRONT);
    let kf_t0 = 0.1 + 5.0 * calib::LIDAR_PERIOD_S;
    let dur = kf_t0 + (cfg.keyframes_per_scene as f64 - 1.0) * calib::KEYFRAME_PERIOD_S + 0.6;
    let t = std::time::Instant::now();
    let mut files = Vec::new();
    let mut by: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
    for (i, w) in ws.iter().enumerate() {
        let world = World::build(cfg.seed, i, *w, dur);
        for k in 0..cfg.keyframes_per_scene {
            let tk = kf_t0 + k as f64 * calib::KEYFRAME_PERIOD_S;
            let sw = radar::scan(&world, &m, tk, (i * 1000 + k) as u64);
            for (p, o) in sw.points.iter().zip(&sw.origins) {
                let name = match o {
                    radar::Origin::Surface { obj }
                        if *obj < depthsense_synth::world::STATIC_OBJ_BASE =>
                    {
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
                };
                by.entry(name)
                    .or_default()
                    .push((p.x as f64).hypot(p.y as f64));
            }
            files.push(sw.points);
        }
    }
    let tot: usize = by.values().map(|v| v.len()).sum();
    for (k, v) in &mut by {
        v.sort_by(f64::total_cmp);
        println!(
            "{k:>24}: {:5.1} %  median range {:.1}",
            100.0 * v.len() as f64 / tot as f64,
            v[v.len() / 2]
        );
    }
    let mut az = [0usize; 8];
    let mut n = 0;
    for f in &files {
        for p in f.iter().filter(|p| p.passes_default_filters()) {
            let a = (p.y as f64).atan2(p.x as f64).to_degrees().abs();
            let i = match a {
                a if a < 5.0 => 0,
                a if a < 10.0 => 1,
                a if a < 20.0 => 2,
                a if a < 30.0 => 3,
                a if a < 40.0 => 4,
                a if a < 50.0 => 5,
                a if a < 60.0 => 6,
                _ => 7,
            };
            az[i] += 1;
            n += 1;
        }
    }
    let mut r10: Vec<f64> = files
        .iter()
        .flat_map(|f| {
            f.iter()
                .filter(|p| {
                    p.passes_default_filters()
                        && (p.y as f64).atan2(p.x as f64).to_degrees().abs() < 10.0
                })
                .map(|p| (p.x as f64).hypot(p.y as f64))
        })
        .collect();
    r10.sort_by(f64::total_cmp);
    println!(
        "kept |az|<10: n {} median range {:.1} p90 {:.1}",
        r10.len(),
        r10[r10.len() / 2],
        r10[r10.len() * 9 / 10]
    );
    let az: Vec<String> = az
        .iter()
        .map(|c| format!("{:.3}", *c as f64 / n as f64))
        .collect();
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
