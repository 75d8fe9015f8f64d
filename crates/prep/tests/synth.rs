//! The data layer against a world whose depth is known exactly: lidar points projected
//! into a keyframe must agree with the rendered truth, and `prepare` must run on it.

use depthsense_nuscenes::depth_png::read_depth_png;
use depthsense_nuscenes::geometry::{cam_from_sensor, Camera};
use depthsense_nuscenes::pcd::read_lidar_pcd_bin;
use depthsense_nuscenes::NuScenes;
use depthsense_prep::layout::{Condition, PreparedIndex};
use depthsense_prep::{prepare, PrepareOptions};
use depthsense_progress::Progress;
use depthsense_synth::{generate, SynthConfig, Weather, TRUTH_DIR};

#[test]
fn lidar_projection_matches_rendered_truth_and_prepare_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("world");
    let cfg = SynthConfig {
        scenes: 1,
        keyframes_per_scene: 2,
        conditions: vec![(Weather::Night, 1.0)],
        ..SynthConfig::default()
    };
    let summary = generate(&root, &cfg, &Progress::hidden()).unwrap();
    assert_eq!(summary.keyframes, 2);
    let nu = NuScenes::load(&root, &cfg.version_name).unwrap();
    assert_eq!(nu.sample.len(), 2);
    let mut rel = Vec::new();
    for s in &nu.sample {
        let cam_sd = nu.keyframe(s.token, "CAM_FRONT").unwrap();
        let lidar_sd = nu.keyframe(s.token, "LIDAR_TOP").unwrap();
        let cs = nu
            .get_calibrated_sensor(cam_sd.calibrated_sensor_token, "t", cam_sd.token, "c")
            .unwrap();
        let cam =
            Camera::from_intrinsic(&cs.camera_intrinsic.unwrap(), cam_sd.width, cam_sd.height);
        let truth =
            read_depth_png(&root.join(TRUTH_DIR).join(format!("{}.png", cam_sd.token))).unwrap();
        assert_eq!((truth.width, truth.height), (cam_sd.width, cam_sd.height));
        let m = cam_from_sensor(&nu, lidar_sd, cam_sd).unwrap().to_f32();
        let scan = read_lidar_pcd_bin(&nu.path_of(lidar_sd)).unwrap();
        for p in &scan.points {
            let pc = depthsense_nuscenes::geometry::apply_f32(&m, [p[0], p[1], p[2]]);
            if let Some((u, v, d)) = cam.project(pc) {
                let t = truth.at(u as u32, v as u32);
                if t > 0.0 {
                    rel.push(((d - t) / t).abs());
                }
            }
        }
    }
    assert!(
        rel.len() > 1000,
        "only {} lidar points hit the truth",
        rel.len()
    );
    rel.sort_by(|a, b| a.total_cmp(b));
    let median = rel[rel.len() / 2];
    assert!(median < 0.01, "median relative error {median}");

    let out = tmp.path().join("prepared");
    let opts = PrepareOptions {
        dataroot: root.clone(),
        version: cfg.version_name.clone(),
        out: out.clone(),
        lidar_sweeps: 2,
        jobs: 1,
        ..Default::default()
    };
    let s = prepare(&opts, &Progress::hidden()).unwrap();
    assert_eq!((s.prepared, s.failed.len()), (2, 0), "{:?}", s.failed);
    let idx: PreparedIndex =
        serde_json::from_slice(&std::fs::read(out.join("index.json")).unwrap()).unwrap();
    assert_eq!(idx.samples.len(), 2);
    let meta: depthsense_prep::layout::SampleMeta = serde_json::from_slice(
        &std::fs::read(out.join(&idx.samples[1].dir).join("meta.json")).unwrap(),
    )
    .unwrap();
    eprintln!(
        "median rel {median}; counts {:?}; annotations {}",
        meta.counts, meta.settings["annotations_present"]
    );
    assert!(meta.counts["lidar_dense_sweeps"] >= 3);
    assert!(meta.counts["lidar_dense_pixels"] > meta.counts["lidar_sparse_pixels"]);
    assert!(meta.counts["radar_in_image"] > 0);
    assert!(meta.counts["lidar_moving_removed"] > 0);
    // The synthetic LIDAR_TOP carries the ego car's own returns (as the real scan does) and
    // every one of the 4 other sweeps loses them (devkit remove_close(1.0)).
    assert!(
        meta.counts["lidar_dense_near_sensor_removed"] > 4 * 2000,
        "{:?}",
        meta.counts
    );
    // The dense target (±2 sweeps, occlusion-filtered, moving boxes removed) against the
    // truth at the same pixels.
    let dense = read_depth_png(&out.join(&idx.samples[1].dir).join("lidar_dense.png")).unwrap();
    let cam_token = &meta.sample_data_tokens["CAM_FRONT"];
    let truth = read_depth_png(&root.join(TRUTH_DIR).join(format!("{cam_token}.png"))).unwrap();
    let mut drel = Vec::new();
    for y in 0..350u32 {
        for x in 0..800u32 {
            let d = dense.at(x, y);
            if d > 0.0 {
                // Nearest truth over the 2x2 full-resolution block of this pixel.
                let t = (0..2)
                    .flat_map(|dy| (0..2).map(move |dx| (2 * x + dx, 2 * (y + 100) + dy)))
                    .map(|(u, v)| truth.at(u, v))
                    .filter(|t| *t > 0.0)
                    .fold(f32::INFINITY, f32::min);
                if t.is_finite() {
                    drel.push(((d - t) / t).abs());
                }
            }
        }
    }
    drel.sort_by(|a, b| a.total_cmp(b));
    let p50 = drel[drel.len() / 2];
    let p90 = drel[drel.len() * 9 / 10];
    eprintln!("dense vs truth: n {} p50 {p50} p90 {p90}", drel.len());
    assert!(
        p50 < 0.02 && p90 < 0.1,
        "dense target off the truth: p50 {p50} p90 {p90}"
    );
    // The world's own split lists tag the samples (one night scene: train), even with
    // `--split all`.
    assert!(
        idx.split_source.starts_with("dataroot"),
        "{}",
        idx.split_source
    );
    assert!(idx
        .samples
        .iter()
        .all(|e| e.conditions == vec![Condition::Night] && e.splits == vec!["train".to_string()]));
    assert_eq!(idx.train_scenes.len(), 1);
    assert!(idx.val_scenes.is_empty() && idx.test_scenes.is_empty());
    // A split with no scene of this world is refused.
    let err = prepare(
        &PrepareOptions {
            split: "test".into(),
            ..opts
        },
        &Progress::hidden(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("--split all"), "{err}");
}

#[test]
fn prepared_synthetic_world_carries_train_val_test_tags() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("world");
    // 9 scenes, 3 per condition: one train, one val and one test scene of each.
    let cfg = SynthConfig {
        scenes: 9,
        keyframes_per_scene: 1,
        ..SynthConfig::tiny()
    };
    generate(&root, &cfg, &Progress::hidden()).unwrap();
    let out = tmp.path().join("prepared");
    let opts = PrepareOptions {
        dataroot: root.clone(),
        version: cfg.version_name.clone(),
        out: out.clone(),
        split: "all".into(),
        radar_sweeps: 1,
        jobs: 0,
        ..Default::default()
    };
    let s = prepare(&opts, &Progress::hidden()).unwrap();
    assert_eq!((s.prepared, s.failed.len()), (9, 0), "{:?}", s.failed);
    let idx: PreparedIndex =
        serde_json::from_slice(&std::fs::read(out.join("index.json")).unwrap()).unwrap();
    assert!(
        idx.split_source.starts_with("dataroot"),
        "{}",
        idx.split_source
    );
    assert_eq!(
        (
            idx.train_scenes.len(),
            idx.val_scenes.len(),
            idx.test_scenes.len()
        ),
        (3, 3, 3)
    );
    let list = |name: &str| -> Vec<String> {
        std::fs::read_to_string(
            root.join(&cfg.version_name)
                .join("splits")
                .join(format!("{name}_scenes.txt")),
        )
        .unwrap()
        .lines()
        .map(String::from)
        .collect()
    };
    assert_eq!(idx.train_scenes, list("train"));
    assert_eq!(idx.val_scenes, list("val"));
    assert_eq!(idx.test_scenes, list("test"));
    for name in ["train", "val", "test"] {
        let entries: Vec<_> = idx
            .samples
            .iter()
            .filter(|e| e.splits == vec![name.to_string()])
            .collect();
        assert_eq!(entries.len(), 3, "{name}");
        let conds: std::collections::BTreeSet<Condition> =
            entries.iter().flat_map(|e| e.conditions.clone()).collect();
        assert_eq!(conds.len(), 3, "{name} lacks a condition: {conds:?}");
        assert!(entries.iter().all(|e| list(name).contains(&e.scene_token)));
    }
    // `--split val` prepares exactly the val scenes' samples.
    let out2 = tmp.path().join("prepared-val");
    let s = prepare(
        &PrepareOptions {
            split: "val".into(),
            out: out2.clone(),
            ..opts
        },
        &Progress::hidden(),
    )
    .unwrap();
    assert_eq!(s.prepared, 3);
    let idx2: PreparedIndex =
        serde_json::from_slice(&std::fs::read(out2.join("index.json")).unwrap()).unwrap();
    assert!(idx2
        .samples
        .iter()
        .all(|e| e.splits == vec!["val".to_string()]));
}
