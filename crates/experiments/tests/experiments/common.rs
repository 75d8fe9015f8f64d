//! Set-up shared by the experiment tests: a hidden progress host, file modification times
//! (resume checks), quick run settings on a toy dataset and a random tiny checkpoint.
#![allow(dead_code)] // each test binary uses its own part

use std::path::Path;
use std::time::SystemTime;

use depthsense_config::device::DeviceArg;
use depthsense_config::training::{
    HardwareOptions, LoadingOptions, ScheduleOptions, ValidationOptions,
};
use depthsense_experiments::runner::RunSettings;
use depthsense_progress::Board;

pub fn hidden() -> Board {
    Board::hidden()
}

pub fn mtime(p: &Path) -> SystemTime {
    std::fs::metadata(p).unwrap().modified().unwrap()
}

/// A random `tiny` network at reduced widths (seed 3) with output frame `out_hw` (height,
/// width), saved as DIR/ck.safetensors.
pub fn tiny_checkpoint(dir: &Path, out_hw: (u32, u32)) -> std::path::PathBuf {
    use depthsense_checkpoint as checkpoint;
    use depthsense_model::DepthNet;
    let (h, w) = (
        format!("out-height={}", out_hw.0),
        format!("out-width={}", out_hw.1),
    );
    let cfg = depthsense_config::ModelConfig::tiny()
        .with_options(&[
            "width=8",
            "decoder-channels=16",
            "head-channels=16",
            "radar-width=8",
            h.as_str(),
            w.as_str(),
        ])
        .unwrap();
    tch::manual_seed(3);
    let vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let _net = DepthNet::new(&vs.root(), &cfg).unwrap();
    let p = dir.join("ck.safetensors");
    checkpoint::save(&p, &vs, &cfg, &serde_json::Value::Null).unwrap();
    p
}

/// The `tiny` preset at reduced widths, no dropout: seconds per run on 2 cores.
pub fn small_model() -> Vec<String> {
    [
        "width=8",
        "decoder-channels=16",
        "head-channels=16",
        "radar-width=8",
        "dropout=0",
    ]
    .map(String::from)
    .to_vec()
}

/// 20 short epochs of batches of two, validated on two samples, on the CPU: enough for the
/// toy dataset's runs to beat the constant-depth baseline several times over (measured: test
/// RMSE 4–6 m against 32 m), a few seconds per run on 2 cores.
pub fn quick_runs(data: &Path) -> RunSettings {
    RunSettings {
        data: data.to_path_buf(),
        preset: "tiny".into(),
        set: small_model(),
        schedule: ScheduleOptions {
            epochs: 20,
            batch_size: 2,
            lr: 2e-3,
            ..Default::default()
        },
        hardware: HardwareOptions {
            device: DeviceArg { name: "cpu".into() },
            ..Default::default()
        },
        loading: LoadingOptions {
            jobs: 2,
            ..Default::default()
        },
        validation: ValidationOptions {
            max_val_samples: Some(2),
            ..Default::default()
        },
    }
}

/// The constant-depth baseline a trained model must beat: the headline RMSE (full image,
/// 80 m cap, per-image mean, SPEC §9) on the `test_scenes` samples of the prepared `data`
/// of predicting one depth everywhere — the mean sparse ground truth of the other (training
/// and validation) scenes. Computed from the files alone (`index.json`, `lidar_sparse.png`
/// read with the `image` crate, value/256 m), not with depthsense's scorer.
pub fn constant_depth_rmse(data: &Path, test_scenes: &[String]) -> f64 {
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(data.join("index.json")).unwrap()).unwrap();
    let gt = |s: &serde_json::Value| -> Vec<f64> {
        let p = data
            .join(s["dir"].as_str().unwrap())
            .join("lidar_sparse.png");
        let img = image::open(&p).unwrap().into_luma16();
        img.pixels()
            .map(|px| px.0[0] as f64 / 256.0)
            .filter(|d| *d > 0.0 && *d <= 80.0)
            .collect()
    };
    let samples = index["samples"].as_array().unwrap();
    let is_test = |s: &serde_json::Value| {
        let name = s["scene_name"].as_str().unwrap();
        test_scenes.iter().any(|t| t == name)
    };
    let train: Vec<f64> = samples
        .iter()
        .filter(|s| !is_test(s))
        .flat_map(gt)
        .collect();
    let c = (train.iter().sum::<f64>() / train.len() as f64).clamp(1.0, 80.0);
    let per_image: Vec<f64> = samples
        .iter()
        .filter(|s| is_test(s))
        .map(gt)
        .filter(|g| !g.is_empty())
        .map(|g| (g.iter().map(|d| (d - c) * (d - c)).sum::<f64>() / g.len() as f64).sqrt())
        .collect();
    assert!(!per_image.is_empty(), "no test image among {test_scenes:?}");
    per_image.iter().sum::<f64>() / per_image.len() as f64
}
