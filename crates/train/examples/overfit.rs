//! Overfit one batch of the toy dataset: a sanity check of model + loss + optimiser.
use std::path::Path;

use depthsense_config::{Fusion, ModelConfig};
use depthsense_data::*;
use depthsense_dataset::Dataset;
use depthsense_model::DepthNet;
use depthsense_train::optim::Optimizer;
use tch::nn::{OptimizerConfig, VarStore};
use tch::Tensor;

/// Optimiser steps of the overfitting run; progress is printed every `PRINT_EVERY_STEPS`.
const STEPS: usize = 40;
/// Steps between two progress lines.
const PRINT_EVERY_STEPS: usize = 5;

/// Writes a toy dataset (1 scene × 4 samples at 128×64) into `dir` and loads its first batch
/// of 4, in order and without radar.
fn load_first_toy_batch(dir: &Path) -> Batch {
    write_toy_dataset(dir, 1, 4, 128, 64, 11).unwrap();
    let ds = Dataset::open(dir).unwrap();
    let plan = EpochPlan {
        entries: ds.split("all"),
        batch_size: 4,
        epoch: 0,
        shuffle: false,
        drop_last: false,
        skip_batches: 0,
        jobs: 1,
        prefetch: 1,
    };
    Loader::start(
        &ds,
        &LoadOptions {
            no_radar: true,
            ..Default::default()
        },
        &plan,
    )
    .unwrap()
    .next()
    .unwrap()
    .unwrap()
}

/// Prints the mean and standard deviation of the image and the mean target depth (m).
fn print_input_stats(img: &Tensor, tgt_m: &Tensor) {
    println!(
        "img mean {:.3} std {:.3} tgt mean {:.2}",
        img.mean(tch::Kind::Float).double_value(&[]),
        img.std(true).double_value(&[]),
        tgt_m.mean(tch::Kind::Float).double_value(&[])
    );
}

/// The tiny preset without fusion or attention at a 128×64 output; the environment variable
/// `HEAD` selects the L1 head and `NODROP` turns dropout off.
fn overfit_model_config() -> ModelConfig {
    let mut cfg = ModelConfig::tiny();
    cfg.fusion = Fusion::None;
    cfg.attention = false;
    if std::env::var("HEAD").is_ok() {
        cfg.head = depthsense_config::HeadKind::L1;
    }
    if std::env::var("NODROP").is_ok() {
        cfg.dropout = 0.0;
    }
    cfg.out_height = 64;
    cfg.out_width = 128;
    cfg
}

/// Prints the loss of step `step` and the RMSE (m) of the eval-mode and train-mode
/// predictions against `tgt_m`, with the standard deviation of the train-mode prediction.
fn print_progress(
    step: usize,
    net: &DepthNet,
    img: &Tensor,
    rad: &Tensor,
    tgt_m: &Tensor,
    loss: &Tensor,
) {
    let d = tch::no_grad(|| net.decode(&net.forward_t(img, rad, false)));
    let dt = tch::no_grad(|| net.decode(&net.forward_t(img, rad, true)));
    let rmse_m = |d: &Tensor| {
        ((d - tgt_m).square().mean(tch::Kind::Float))
            .sqrt()
            .double_value(&[])
    };
    println!(
        "{step}: loss {:.3} rmse eval {:.2} train-mode {:.2} pred std {:.2}",
        loss.double_value(&[]),
        rmse_m(&d),
        rmse_m(&dt),
        dt.std(true).double_value(&[])
    );
}

/// Trains `net` (parameters in `vs`) on the one batch for `STEPS` steps at learning rate `lr`,
/// with this crate's SGD when `mine`, else with tch's, printing progress on the way.
fn overfit(
    vs: &VarStore,
    net: &DepthNet,
    img: &Tensor,
    rad: &Tensor,
    tgt_m: &Tensor,
    mine: bool,
    lr: f64,
) {
    let mut sgd = depthsense_train::sgd::Sgd::new(vs, 0.9, 1e-4);
    let mut opt = tch::nn::Sgd {
        momentum: 0.9,
        dampening: 0.0,
        wd: 1e-4,
        nesterov: false,
    }
    .build(vs, lr)
    .unwrap();
    println!("trainable {}", sgd.len());
    for i in 0..STEPS {
        let out = net.forward_t(img, rad, true);
        let loss = net.loss(&out, tgt_m);
        if mine {
            sgd.zero_grad();
            loss.backward();
            sgd.step(lr);
        } else {
            opt.backward_step(&loss);
        }
        if i % PRINT_EVERY_STEPS == 0 {
            print_progress(i, net, img, rad, tgt_m, &loss);
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mine = args.get(1).map(String::as_str) != Some("tch");
    let lr: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1e-2);
    let tmp = tempfile::tempdir().unwrap();
    let b = load_first_toy_batch(tmp.path());
    let (img, rad, tgt) = depthsense_infer::upload::batch_tensors(&b, tch::Device::Cpu);
    print_input_stats(&img, &tgt);
    let cfg = overfit_model_config();
    tch::manual_seed(0);
    let vs = VarStore::new(tch::Device::Cpu);
    let net = DepthNet::new(&vs.root(), &cfg).unwrap();
    overfit(&vs, &net, &img, &rad, &tgt, mine, lr);
}
