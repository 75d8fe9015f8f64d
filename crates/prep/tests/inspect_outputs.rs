//! `inspect` reads depthsense's own outputs (issue 33): a prepared folder, a prepared sample
//! folder with every map summarised (`radar_points.bin` as radar returns, not as lidar), a
//! 16-bit depth PNG with its valid pixels and depth range, and an evaluation's tables.json.

use depthsense_prep::inspect::{expand_paths, inspect};
use depthsense_prep::layout::PreparedIndex;
use depthsense_prep::{prepare, PrepareOptions};
use depthsense_progress::Progress;
use depthsense_synth::{generate, SynthConfig, Weather};

#[test]
fn prepared_folders_samples_depth_pngs_and_tables_are_summarised() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("world");
    let cfg = SynthConfig {
        scenes: 1,
        keyframes_per_scene: 2,
        conditions: vec![(Weather::Night, 1.0)],
        ..SynthConfig::default()
    };
    generate(&root, &cfg, &Progress::hidden()).unwrap();
    let out = tmp.path().join("prepared");
    let opts = PrepareOptions {
        dataroot: root,
        version: cfg.version_name.clone(),
        out: out.clone(),
        jobs: 1,
        ..Default::default()
    };
    prepare(&opts, &Progress::hidden()).unwrap();
    let ix: PreparedIndex =
        serde_json::from_slice(&std::fs::read(out.join("index.json")).unwrap()).unwrap();

    let p = inspect(&out).unwrap();
    assert_eq!(p["kind"], "prepared");
    assert_eq!(p["samples"], 2);
    assert_eq!(p["conditions"]["night"], 2);
    assert_eq!(p["settings"]["radar_sweeps"], 5);

    let sample = out.join(&ix.samples[0].dir);
    let s = inspect(&sample).unwrap();
    assert_eq!(s["kind"], "prepared_sample");
    assert_eq!(s["sample_token"], ix.samples[0].sample_token.as_str());
    let file = |name: &str| {
        s["files"]
            .as_array()
            .unwrap()
            .iter()
            .find(|f| f["path"] == name)
            .unwrap_or_else(|| panic!("{name} missing: {s}"))
            .clone()
    };
    let points = file("radar_points.bin");
    assert_eq!(points["kind"], "radar_points");
    assert!(points["points"].as_u64().unwrap() > 0, "{points}");
    let lidar = file("lidar_sparse.png");
    assert_eq!(lidar["kind"], "depth_png");
    assert_eq!(
        (lidar["width"].as_u64(), lidar["height"].as_u64()),
        (Some(800), Some(350))
    );
    let valid = lidar["valid_pixels"].as_u64().unwrap();
    assert!(valid > 100, "{lidar}");
    let (lo, hi) = (
        lidar["depth_m"]["min"].as_f64().unwrap(),
        lidar["depth_m"]["max"].as_f64().unwrap(),
    );
    assert!(lo > 0.0 && hi > lo && hi < 200.0, "{lidar}");
    assert_eq!(file("image.png")["kind"], "image");
    assert!(
        s["files"]
            .as_array()
            .unwrap()
            .iter()
            .all(|f| f.get("error").is_none()),
        "{s}"
    );

    // A depth PNG on its own, as `predict` writes depth.png.
    let d = inspect(&sample.join("radar_height.png")).unwrap();
    assert_eq!(d["kind"], "depth_png");

    // A prepared folder among other paths is one entry, not its thousands of files.
    assert_eq!(
        expand_paths(&[out.clone(), sample.clone()]).unwrap(),
        [out, sample]
    );

    // tables.json: each model's headline row.
    let mut ev = depthsense_metrics::Evaluator::new(Default::default()).unwrap();
    let gt = [10.0f32, 20.0, 0.0, 40.0];
    ev.add(&depthsense_metrics::EvalImage {
        pred_m: &[11.0, 18.0, 5.0, 40.0],
        gt_m: &gt,
        lowheight: None,
        conditions: &["night"],
    })
    .unwrap();
    let report = ev.finish();
    let tables = tmp.path().join("tables.json");
    std::fs::write(
        &tables,
        serde_json::to_vec(&serde_json::json!({"models": [{"name": "fusion", "report": report}]}))
            .unwrap(),
    )
    .unwrap();
    let t = inspect(&tables).unwrap();
    assert_eq!(t["kind"], "tables");
    assert_eq!(t["models"][0]["name"], "fusion");
    let rmse = t["models"][0]["headline"]["rmse_m"].as_f64().unwrap();
    assert!((rmse - (5.0f64 / 3.0).sqrt()).abs() < 1e-6, "{t}"); // errors 1, 2, 0 m
    assert_eq!(t["models"][0]["headline"]["images"], 1);
}
