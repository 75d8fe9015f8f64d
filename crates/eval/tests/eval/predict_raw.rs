//! `predict` on raw files (JPEG + radar PCD + calibration JSON) builds the same network input
//! as `prepare` does for the real nuScenes keyframe of ../shared/fixtures/nuscenes-kf0.

use depthsense_prep::PrepareOptions;

#[test]
fn raw_files_give_the_prepared_maps() {
    let Some(root) = depthsense_testkit::fixture("nuscenes-kf0") else {
        return;
    };
    let token = "ca9a282c9e77460f8360f564131a8af5";
    let opts = PrepareOptions {
        dataroot: root.clone(),
        version: "v1.0-mini".into(),
        radar_sweeps: 1,
        radar_channels: vec!["RADAR_FRONT".into()],
        ..PrepareOptions::default()
    };
    let nu = depthsense_nuscenes::tables::NuScenes::load(&root, "v1.0-mini").unwrap();
    let sample = nu
        .sample
        .iter()
        .find(|s| s.token == depthsense_nuscenes::tables::Token::parse(token))
        .unwrap();
    let maps = depthsense_prep::pipeline::compute_sample(&nu, sample, &opts).unwrap();
    let find = |dir: &str, ext: &str| {
        std::fs::read_dir(root.join("samples").join(dir))
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.to_string_lossy().ends_with(ext))
            .unwrap()
    };
    let jpeg = find("CAM_FRONT", ".jpg");
    let pcd = find("RADAR_FRONT", ".pcd");
    let tmp = tempfile::tempdir().unwrap();
    let calib = tmp.path().join("calib.json");
    let name = pcd.file_name().unwrap().to_string_lossy().into_owned();
    std::fs::write(
        &calib,
        serde_json::to_vec(&serde_json::json!({
            "camera_intrinsic": maps.meta.intrinsics_full,
            "cam_from_radar": { name.clone(): maps.meta.cam_from_radar["RADAR_FRONT"] },
        }))
        .unwrap(),
    )
    .unwrap();
    let raw = depthsense_eval::predict::input_from_raw(&jpeg, &[pcd], &calib, true).unwrap();
    assert_eq!(raw.image.as_raw(), &maps.image_rgb);
    assert!(maps.radar_raw.valid_count() > 10);
    // The maps as prepare stores them (16-bit PNG), bit for bit: the JSON carries the 4x4
    // prepare composed, and the radar goes through prepare's own sweep function.
    let stored = |m: &depthsense_nuscenes::depth_png::DepthMap| {
        depthsense_eval::predict::as_stored(m.clone()).unwrap()
    };
    assert!(raw.radar_raw == stored(&maps.radar_raw), "raw maps differ");
    assert!(
        raw.radar_height == stored(&maps.radar_height),
        "height maps differ"
    );
    // Through the token path as well.
    let tok = depthsense_eval::predict::input_from_token(&root, "v1.0-mini", token, &opts).unwrap();
    assert!(tok.radar_raw == stored(&maps.radar_raw));
    assert!(tok.gt.unwrap() == stored(&maps.lidar_sparse));
    // A calibration without the radar file is a clear error naming it.
    std::fs::write(
        &calib,
        br#"{"camera_intrinsic": [[1,0,0],[0,1,0],[0,0,1]], "cam_from_radar": {}}"#,
    )
    .unwrap();
    let err = depthsense_eval::predict::input_from_raw(
        &jpeg,
        &[find("RADAR_FRONT", ".pcd")],
        &calib,
        true,
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("no cam_from_radar entry") && err.contains(&name),
        "{err}"
    );
}

/// Every sweep (issue 33): raw files with a calibration written by `depthsense calibration`
/// (`calibration::for_sample`), a sample token and the prepared sample give the same radar
/// maps, image and ground truth bit for bit, so the same depth; the keyframe sweeps alone give
/// a sparser radar, and `predict` warns about it.
#[test]
fn raw_files_token_and_prepared_sample_give_one_input_bit_for_bit() {
    use depthsense_eval::predict::{
        input_from_prepared, input_from_raw, input_from_token, predict, radar_warnings,
    };
    use depthsense_prep::calibration::{for_sample, write, RadarSettings};
    use depthsense_progress::Progress;
    use depthsense_synth::{generate, SynthConfig, Weather};

    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("world");
    let cfg = SynthConfig {
        scenes: 1,
        keyframes_per_scene: 3,
        conditions: vec![(Weather::Day, 1.0)],
        ..SynthConfig::default()
    };
    generate(&root, &cfg, &Progress::hidden()).unwrap();
    let out = tmp.path().join("prepared");
    let opts = PrepareOptions {
        dataroot: root.clone(),
        version: cfg.version_name.clone(),
        out: out.clone(),
        lidar_sweeps: 0,
        jobs: 1,
        ..Default::default()
    };
    let s = depthsense_prep::prepare(&opts, &Progress::hidden()).unwrap();
    assert_eq!(s.failed.len(), 0, "{:?}", s.failed);
    let nu = depthsense_nuscenes::tables::NuScenes::load(&root, &cfg.version_name).unwrap();
    let sample = nu.sample.last().unwrap();
    let token = sample.token.to_string();

    let calib = for_sample(&nu, sample, &opts).unwrap();
    assert_eq!(calib.radar.iter().filter(|r| r.sweep == 0).count(), 3);
    assert!(
        calib.radar.len() > 6,
        "earlier sweeps listed: {}",
        calib.radar.len()
    );
    let calib_path = tmp.path().join("calib.json");
    write(&calib_path, &calib).unwrap();
    let jpeg = std::path::PathBuf::from(calib.camera_file.clone().unwrap());

    let prepared = input_from_prepared(&out.join(&token)).unwrap();
    let raw = input_from_raw(&jpeg, &[], &calib_path, true).unwrap();
    let tok = input_from_token(&root, &cfg.version_name, &token, &opts).unwrap();
    for other in [&raw, &tok] {
        assert_eq!(other.image, prepared.image);
        assert!(
            other.radar_raw == prepared.radar_raw,
            "raw radar maps differ"
        );
        assert!(
            other.radar_height == prepared.radar_height,
            "height maps differ"
        );
    }
    assert!(tok.gt == prepared.gt, "ground truth differs");
    let trained = prepared.radar_settings.clone().unwrap();
    assert_eq!(trained, RadarSettings::of(&opts));
    assert!(radar_warnings(Some(&trained), &raw).is_empty());

    // The same depth from a network (random weights) on the three.
    tch::manual_seed(0);
    let vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let mc = depthsense_config::ModelConfig::tiny()
        .with_options(&["width=8", "decoder-channels=16", "head-channels=16"])
        .unwrap();
    let net = depthsense_model::DepthNet::new(&vs.root(), &mc).unwrap();
    let radar = Some(depthsense_config::RadarInput::Height);
    let d = |i| predict(&net, i, radar, tch::Device::Cpu).unwrap();
    let want = d(&prepared);
    assert!(d(&raw) == want && d(&tok) == want, "depth differs");

    // The keyframe sweeps alone: fewer radar pixels, and a warning naming what is missing.
    let keyframe_files: Vec<std::path::PathBuf> = calib
        .radar
        .iter()
        .filter(|r| r.sweep == 0)
        .map(|r| r.file.clone().into())
        .collect();
    let sparse = input_from_raw(&jpeg, &keyframe_files, &calib_path, true).unwrap();
    assert!(
        sparse.radar_raw.valid_count() < prepared.radar_raw.valid_count(),
        "{} vs {}",
        sparse.radar_raw.valid_count(),
        prepared.radar_raw.valid_count()
    );
    let w = radar_warnings(Some(&trained), &sparse);
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(
        w[0].contains("1 radar sweep(s) per channel where training had 5"),
        "{w:?}"
    );
}
