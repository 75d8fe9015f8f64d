//! `depthsense bench train`: training images/s (forward + backward + SGD step) and
//! data-loader images/s (decode + augment + normalise + batch, with prefetch).

use std::path::PathBuf;
use std::time::Instant;

use depthsense_config::ModelConfig;
use depthsense_data::{EpochPlan, LoadOptions, Loader};
use depthsense_dataset::Dataset;
use depthsense_model::DepthNet;
use serde::{Deserialize, Serialize};
use tch::nn::VarStore;

use crate::optim::Optimizer;
use crate::sgd::Sgd;
use crate::step::{forward_loss, step_precision};
use depthsense_infer::upload::upload_batch;
use depthsense_infer::NetError;

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BenchTrainOptions {
    /// Prepared data; None = a generated 800x350 toy dataset in a temporary directory.
    pub data: Option<PathBuf>,
    pub preset: String,
    pub batch_size: usize,
    /// Timed training iterations (after `warmup`).
    pub iterations: usize,
    pub warmup: usize,
    /// Batches timed for the loader.
    pub loader_batches: usize,
    pub device: String,
    pub jobs: usize,
    pub amp: bool,
    /// `key=value` model-config overrides (e.g. `input-downscale=2`).
    #[serde(default)]
    pub set: Vec<String>,
}

impl Default for BenchTrainOptions {
    fn default() -> Self {
        Self {
            data: None,
            preset: "paper".into(),
            batch_size: 8,
            iterations: 3,
            warmup: 1,
            loader_batches: 8,
            device: "auto".into(),
            jobs: 0,
            amp: false,
            set: Vec::new(),
        }
    }
}

/// Run the benchmark; returns the JSON report.
pub fn bench_train(
    opts: &BenchTrainOptions,
    progress: &depthsense_progress::Progress,
) -> Result<serde_json::Value, NetError> {
    let device = depthsense_model::device::parse_device(&opts.device)?;
    depthsense_model::device::autotune_fixed_size(device);
    let (root, _tmp) = bench_data(opts, progress)?;
    let ds = Dataset::open(&root)?;
    let entries = ds.split("all");
    let mut cfg = ModelConfig::preset(&opts.preset)?.with_options(&opts.set)?;
    let radar = cfg.radar_input_for(None)?;
    let load = LoadOptions {
        radar: radar.unwrap_or_default(),
        no_radar: radar.is_none(),
        augment: true,
        seed: 1,
        ..LoadOptions::default()
    };
    let jobs = depthsense_data::loader_threads(opts.jobs);

    // Full batches only (when there are enough samples): an epoch's last, smaller batch is a
    // new input shape, and cuDNN autotunes every convolution for it once — 10.8 s of one
    // timed step at the paper preset on an H200 (2026-12-04), not the steady step rate.
    let full_batches = entries.len() >= opts.batch_size;
    let plan = |epoch| EpochPlan {
        entries: entries.clone(),
        batch_size: opts.batch_size,
        epoch,
        shuffle: true,
        drop_last: full_batches,
        skip_batches: 0,
        jobs,
        prefetch: 4,
    };
    progress.set_message("loader");
    let (images, loader_ips) = time_loader(opts, &ds, &load, &plan)?;
    let (width, height) = ds.frame_size()?;
    (cfg.out_height, cfg.out_width) = (height.into(), width.into());
    // Training steps, with the loader running in the background as in `train`.
    progress.set_message("training steps");
    let (timed_images, timed_secs, step_secs) =
        time_steps(opts, &cfg, &ds, &load, &plan, device, progress)?;
    Ok(serde_json::json!({
        "benchmark": "train",
        "device": depthsense_model::device::describe(device),
        "preset": opts.preset,
        "batch_size": opts.batch_size,
        "frame": [width, height],
        "amp": opts.amp && device.is_cuda(),
        "amp_dtype": "bf16",
        "train_images_per_s": timed_images as f64 / timed_secs.max(1e-9),
        "train_step_seconds": step_secs,
        "loader_images_per_s": loader_ips,
        "loader_threads": jobs,
        "loader_images": images,
        "cpu_threads": std::thread::available_parallelism().map_or(0, |n| n.get()),
        "torch_threads": tch::get_num_threads(),
    }))
}

/// The prepared folder the benchmark reads: `--data`, or a toy 800×350 world written to a
/// temporary folder (removed when the returned guard drops).
fn bench_data(
    opts: &BenchTrainOptions,
    progress: &depthsense_progress::Progress,
) -> Result<(PathBuf, Option<tempfile::TempDir>), NetError> {
    if let Some(p) = &opts.data {
        return Ok((p.clone(), None));
    }
    let tmp = tempfile::tempdir().map_err(|e| NetError::io(&std::env::temp_dir(), e))?;
    progress.set_message("writing a toy 800x350 dataset");
    let n = (opts.batch_size * opts.loader_batches.max(2)).clamp(8, 64);
    depthsense_data::write_toy_dataset(tmp.path(), 2, n.div_ceil(2), 800, 350, 1)?;
    Ok((tmp.path().to_path_buf(), Some(tmp)))
}

/// Images through the loader alone: (images, images per second).
fn time_loader(
    opts: &BenchTrainOptions,
    ds: &Dataset,
    load: &LoadOptions,
    plan: &dyn Fn(u64) -> EpochPlan,
) -> Result<(usize, f64), NetError> {
    let t = Instant::now();
    let mut images = 0usize;
    let mut epoch = 0;
    'outer: loop {
        for b in Loader::start(ds, load, &plan(epoch))? {
            images += b?.size;
            if images >= opts.loader_batches * opts.batch_size {
                break 'outer;
            }
        }
        epoch += 1;
    }
    Ok((images, images as f64 / t.elapsed().as_secs_f64()))
}

/// Warm-up, then timed training steps: (timed images, timed seconds, each step's seconds).
#[allow(clippy::too_many_arguments)]
fn time_steps(
    opts: &BenchTrainOptions,
    cfg: &ModelConfig,
    ds: &Dataset,
    load: &LoadOptions,
    plan: &dyn Fn(u64) -> EpochPlan,
    device: tch::Device,
    progress: &depthsense_progress::Progress,
) -> Result<(usize, f64, Vec<f64>), NetError> {
    tch::manual_seed(0);
    let vs = VarStore::new(device);
    let net = DepthNet::new(&vs.root(), cfg)?;
    let mut sgd = Sgd::new(&vs, 0.9, 1e-4);
    let mut done = 0usize;
    let mut timed_images = 0usize;
    let mut timed_secs = 0.0;
    let mut step_secs = vec![];
    let total = opts.warmup + opts.iterations.max(1);
    let mut epoch = 100;
    'train: loop {
        for b in Loader::start(ds, load, &plan(epoch))? {
            let b = b?;
            let t = Instant::now();
            let bt = upload_batch(&b, device);
            // The training step's forward and loss, as `train` runs them (bf16 with --amp).
            let loss = forward_loss(&net, &bt, step_precision(opts.amp));
            sgd.zero_grad();
            loss.backward();
            sgd.step(1e-3);
            let _ = loss.double_value(&[]); // synchronises CUDA
            let dt = t.elapsed().as_secs_f64();
            done += 1;
            progress.set_message(format!("step {done}/{total}: {dt:.2} s"));
            if done > opts.warmup {
                timed_images += b.size;
                timed_secs += dt;
                step_secs.push(dt);
            }
            if done >= total {
                break 'train;
            }
        }
        epoch += 1;
    }
    Ok((timed_images, timed_secs, step_secs))
}
