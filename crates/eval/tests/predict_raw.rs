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
    // Same pixels; depths equal up to f32 rounding of the transform (prepare composes the
    // transforms itself, the JSON carries the composed 4x4).
    let same = |a: &depthsense_nuscenes::depth_png::DepthMap,
                b: &depthsense_nuscenes::depth_png::DepthMap| {
        let mut differ = 0;
        for (x, y) in a.depth_m.iter().zip(&b.depth_m) {
            if (*x > 0.0) != (*y > 0.0) {
                differ += 1;
            } else {
                assert!((x - y).abs() < 1e-3, "{x} vs {y}");
            }
        }
        differ
    };
    let d_raw = same(&raw.radar_raw, &maps.radar_raw);
    let d_h = same(&raw.radar_height, &maps.radar_height);
    eprintln!("differing pixels: raw {d_raw}, height {d_h}");
    assert_eq!(d_raw, 0);
    assert!(d_h <= 4, "{d_h} height pixels differ");
    // Through the token path as well.
    let tok = depthsense_eval::predict::input_from_token(&root, "v1.0-mini", token, &opts).unwrap();
    assert_eq!(tok.radar_raw, maps.radar_raw);
    assert_eq!(tok.gt.unwrap(), maps.lidar_sparse);
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
