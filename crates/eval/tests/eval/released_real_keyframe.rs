//! The authors' checkpoint layout on the real keyframe (issue 22, SPEC §6.1, §7): the reference
//! network of `crates/checkpoint/tests/released_reference.py` — its module tree named as the
//! authors' `RVMDE` (`retinanet`, `resnet_radar`, a top-level `conv_radar`, `concat_process`) —
//! writes a state dict with `torch.save(model.state_dict())` and predicts the real nuScenes
//! keyframe `../shared/fixtures/nuscenes-kf0` from the image and height-extended radar that
//! depthsense computes for it. depthsense loads that `.pth` through the `predict --config
//! released` path (`evaluate::load_model`, `predict::predict`) and must give the same depth on
//! ≥ 99.5 % of the 800x350 pixels. Narrow widths (ResNet-101 layout at /8) keep it to seconds.
//! Skips when the fixture or the workspace `.venv` (torch) is absent.

use std::path::Path;

use crate::reference;

use depthsense_eval::evaluate::load_model;
use depthsense_eval::predict::{input_from_token, predict};

const SAMPLE: &str = "ca9a282c9e77460f8360f564131a8af5";

fn f32_file(path: &Path, values: &[f32]) {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn released_preset_predicts_like_the_authors_network_on_the_real_keyframe() {
    let Some(kf0) = depthsense_testkit::fixture("nuscenes-kf0") else {
        return;
    };
    let popts = depthsense_prep::PrepareOptions {
        dataroot: kf0.clone(),
        version: "v1.0-mini".into(),
        lidar_sweeps: 0,
        jobs: 1,
        ..Default::default()
    };
    let input = input_from_token(&kf0, "v1.0-mini", SAMPLE, &popts).unwrap();
    let (w, h) = input.image.dimensions();
    assert_eq!((w, h), (800, 350), "SPEC §3 training frame");
    let hw = (w * h) as usize;
    let dir = tempfile::tempdir().unwrap();
    // The network inputs as depthsense builds them: RGB in [0, 1] (channel-major) and the
    // height-extended radar map in metres.
    let mut rgb = vec![0f32; 3 * hw];
    for (i, p) in input.image.pixels().enumerate() {
        for c in 0..3 {
            rgb[c * hw + i] = p[c] as f32 / 255.0;
        }
    }
    let strips = input
        .radar_height
        .depth_m
        .iter()
        .filter(|d| **d > 0.0)
        .count();
    assert!(strips > 1000, "the keyframe's radar strips: {strips} px");
    f32_file(&dir.path().join("rgb.f32"), &rgb);
    f32_file(&dir.path().join("radar.f32"), &input.radar_height.depth_m);

    let narrow = [
        "width=8",
        "radar-width=8",
        "decoder-channels=16",
        "head-channels=32",
        "radar-out-channels=16",
    ]
    .map(String::from);
    let params = serde_json::json!({
        "seed": 11,
        "width": 8,
        "blocks": [3, 4, 23, 3],
        "decoder_channels": 16,
        "radar_width": 8,
        "radar_channels": 1,
        "radar_out_channels": 16,
        "head_channels": 32,
        "bins": 80,
        "height": h,
        "width_px": w,
        "bn_spread": 0.3,
        "head_gain": 20.0,
        "radar_strips": 0,
        "alpha": 1.0,
        "beta": 80.0,
        "decode_offset": 0.3,
        "rgb_file": dir.path().join("rgb.f32"),
        "radar_file": dir.path().join("radar.f32"),
    });
    let Some(_) = reference::run_reference(dir.path(), &params) else {
        return;
    };
    // The state dict has the authors' layout: conv_radar on the top level.
    let keys: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("keys.json")).unwrap()).unwrap();
    assert!(keys.get("conv_radar.0.weight").is_some(), "{keys}");
    assert!(keys
        .as_object()
        .unwrap()
        .keys()
        .all(|k| !k.contains("backbone.conv_radar")));

    let pth = dir.path().join("weights.pth");
    let (loaded, report) = load_model(&pth, Some("released"), &narrow, tch::Device::Cpu).unwrap();
    let report = report.expect("a .pth gives an import report");
    assert!(report.left_random.is_empty(), "{report}");
    assert!(report.unused.is_empty(), "{:?}", report.unused);
    let radar = loaded.config.radar_input_for(None).unwrap();
    let ours = predict(&loaded.net, &input, radar, tch::Device::Cpu).unwrap();
    let theirs: Vec<f32> = std::fs::read(dir.path().join("depth.f32"))
        .unwrap()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(theirs.len(), hw);
    let same = ours
        .depth_m
        .iter()
        .zip(&theirs)
        .filter(|(a, b)| (**a - **b).abs() < 1e-3)
        .count();
    let frac = same as f64 / hw as f64;
    eprintln!(
        "same depth as the authors'-layout PyTorch network on {:.3} % of {hw} pixels",
        100.0 * frac
    );
    assert!(frac >= 0.995, "only {:.3} % of pixels agree", 100.0 * frac);
}
