//! Train the tiny preset on a generated toy dataset and print the validation curve.
//! `cargo run -p depthsense-experiments --example toy_train -- EPOCHS LR [late|none]`
use std::path::{Path, PathBuf};

use depthsense_config::device::DeviceArg;
use depthsense_config::training::{HardwareOptions, LoadingOptions, ScheduleOptions};
use depthsense_config::{Fusion, ModelConfig};
use depthsense_train::trainer::{train, TrainOptions, TrainSummary};

/// Image width (pixels) of the toy dataset; its height is 64.
const TOY_WIDTH_PX: usize = 128;

/// Training options for the tiny preset with `fusion` on the toy dataset at `data`, writing
/// its run to `out`: `epochs` at learning rate `lr`, batch 4, seed 5, on the CPU; dropout
/// from the environment variable `DROPOUT` (default 0).
fn toy_train_options(
    data: PathBuf,
    out: PathBuf,
    epochs: usize,
    lr: f64,
    fusion: Fusion,
) -> TrainOptions {
    let mut model = ModelConfig::tiny();
    model.fusion = fusion;
    model.dropout = std::env::var("DROPOUT")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0.0);
    TrainOptions {
        data,
        out,
        model,
        schedule: ScheduleOptions {
            epochs,
            batch_size: 4,
            lr,
            seed: 5,
            ..Default::default()
        },
        loading: LoadingOptions {
            jobs: 2,
            ..Default::default()
        },
        hardware: HardwareOptions {
            device: DeviceArg { name: "cpu".into() },
            ..Default::default()
        },
        ..TrainOptions::default()
    }
}

/// Prints the validation RMSE curve (rounded to cm) and the last loss with the training time.
fn print_train_summary(s: &TrainSummary) {
    println!(
        "val {:?}",
        s.val
            .iter()
            .map(|v| (v.rmse * 100.0).round() / 100.0)
            .collect::<Vec<_>>()
    );
    println!("loss last {:?} in {:.1}s", s.losses.last(), s.seconds);
}

/// Predicts the first sample of `root/data` with the checkpoint `root/run/last.safetensors`
/// and prints, for a few rows, the predicted depth (m) at column 9 against the largest sparse
/// ground truth (m) of columns 9–11.
fn print_prediction_rows(root: &Path) {
    let l =
        depthsense_checkpoint::load(&root.join("run/last.safetensors"), tch::Device::Cpu).unwrap();
    let ds = depthsense_dataset::Dataset::open(&root.join("data")).unwrap();
    let e = &ds.split("all")[0];
    let inp = depthsense_eval::predict::input_from_prepared(&ds.sample_dir(e)).unwrap();
    let radar = l.config.radar_input_for(None).unwrap();
    let d = depthsense_eval::predict::predict(&l.net, &inp, radar, tch::Device::Cpu).unwrap();
    let gt = inp.gt.unwrap();
    for v in [5usize, 20, 30, 40, 50, 63] {
        println!(
            "row {v}: pred {:.2} gt(sparse) {:.2}",
            d.depth_m[v * TOY_WIDTH_PX + 9],
            gt.depth_m[v * TOY_WIDTH_PX + 9]
                .max(gt.depth_m[v * TOY_WIDTH_PX + 10])
                .max(gt.depth_m[v * TOY_WIDTH_PX + 11])
        );
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let epochs: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(10);
    let lr: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1e-2);
    let fusion = if args.get(3).map(String::as_str) == Some("none") {
        Fusion::None
    } else {
        Fusion::Late
    };
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    depthsense_data::write_toy_dataset(&data, 5, 4, TOY_WIDTH_PX as u32, 64, 11).unwrap();
    let o = toy_train_options(data, tmp.path().join("run"), epochs, lr, fusion);
    let s = train(&o, &depthsense_progress::Progress::hidden()).unwrap();
    print_train_summary(&s);
    print_prediction_rows(tmp.path());
}
