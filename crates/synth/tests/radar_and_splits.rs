//! The synthetic RADAR_FRONT against the real one, and the world's train / val / test lists.
//!
//! Real RADAR_FRONT (404 keyframe files of v1.0-mini, `../shared/fixtures/radar-front-mini`,
//! devkit filters): 125 points per file (median), 50 % kept, kept range p10/p50/p90
//! 16.0 / 47.0 / 91.1 m, RCS 0.0 / 6.5 / 18.5 dBsm (docs/design-synth.md, "Radar statistics").

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use depthsense_nuscenes::pcd::read_radar_pcd;
use depthsense_nuscenes::NuScenes;
use depthsense_progress::Progress;
use depthsense_synth::radar_stats::radar_stats;
use depthsense_synth::{generate, SynthConfig};

/// The demo configuration (day/night/rain 0.5/0.25/0.25, seed 0) at a small size: 12 scenes
/// (6 day, 3 night, 3 rain) × 2 keyframes.
fn cfg() -> SynthConfig {
    SynthConfig {
        scenes: 12,
        keyframes_per_scene: 2,
        ..SynthConfig::demo()
    }
}

fn root() -> &'static Path {
    static W: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &W.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("synth");
        generate(&root, &cfg(), &Progress::hidden()).unwrap();
        (dir, root)
    })
    .1
}

#[test]
fn radar_front_matches_the_real_statistics() {
    let cfg = cfg();
    let nu = NuScenes::load(root(), &cfg.version_name).unwrap();
    let files: Vec<_> = nu
        .sample
        .iter()
        .map(|s| {
            let sd = nu.keyframe(s.token, "RADAR_FRONT").unwrap();
            read_radar_pcd(&nu.path_of(sd)).unwrap().points
        })
        .collect();
    assert_eq!(files.len(), cfg.scenes * cfg.keyframes_per_scene);
    let s = radar_stats(&files);
    eprintln!("synthetic RADAR_FRONT: {s}");
    assert!(s.points_max <= 125);
    assert!(s.points_median >= 100.0, "points per file: {s}");
    assert!(
        (0.35..=0.65).contains(&s.kept_fraction),
        "kept by the devkit filters: {s}"
    );
    assert!(
        s.range_kept_m[1] >= 35.0,
        "median range of kept points: {s}"
    );
}

#[test]
fn the_real_statistics_are_what_the_docs_say() {
    let Some(dir) = depthsense_testkit::fixture("radar-front-mini") else {
        return;
    };
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "pcd"))
        .collect();
    paths.sort();
    let files: Vec<_> = paths
        .iter()
        .map(|p| read_radar_pcd(p).unwrap().points)
        .collect();
    let s = radar_stats(&files);
    eprintln!("real RADAR_FRONT: {s}");
    assert_eq!(s.files, 404);
    assert_eq!(
        (s.points_median, s.points_min, s.points_max),
        (125.0, 52, 125)
    );
    assert!((s.kept_fraction - 0.50).abs() < 0.005, "{s}");
    let close = |a: [f64; 3], b: [f64; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 0.06);
    assert!(close(s.range_kept_m, [16.0, 47.0, 91.1]), "{s}");
    assert!(close(s.rcs_kept_dbsm, [0.0, 6.5, 18.5]), "{s}");
}

#[test]
fn split_lists_are_disjoint_complete_and_span_every_condition() {
    let cfg = cfg();
    let vdir = root().join(&cfg.version_name);
    let scenes: Vec<serde_json::Value> =
        serde_json::from_slice(&std::fs::read(vdir.join("scene.json")).unwrap()).unwrap();
    let cond: BTreeMap<String, String> = scenes
        .iter()
        .map(|s| {
            let d = s["description"].as_str().unwrap().to_lowercase();
            let c = if d.contains("night") {
                "night"
            } else if d.contains("rain") {
                "rain"
            } else {
                "day"
            };
            (s["token"].as_str().unwrap().to_string(), c.to_string())
        })
        .collect();
    let all_conds: BTreeSet<&String> = cond.values().collect();
    assert_eq!(all_conds.len(), 3);
    let list = |name: &str| -> Vec<String> {
        std::fs::read_to_string(vdir.join("splits").join(format!("{name}_scenes.txt")))
            .unwrap()
            .lines()
            .map(String::from)
            .collect()
    };
    let (train, val, test) = (list("train"), list("val"), list("test"));
    let mut seen = BTreeSet::new();
    for t in train.iter().chain(&val).chain(&test) {
        assert!(cond.contains_key(t), "{t} is not a scene of the world");
        assert!(seen.insert(t.clone()), "{t} is in two lists");
    }
    assert_eq!(seen.len(), scenes.len(), "a scene is in no list");
    for (name, l) in [("val", &val), ("test", &test), ("train", &train)] {
        let c: BTreeSet<&String> = l.iter().map(|t| &cond[t]).collect();
        assert_eq!(c, all_conds, "{name} lacks a condition");
    }
    assert!(train.len() >= val.len() + test.len());
}
