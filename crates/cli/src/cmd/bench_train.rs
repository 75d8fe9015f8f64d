//! `depthsense bench train`: training images/s and data-loader images/s, as JSON.

use std::path::PathBuf;
use std::process::ExitCode;

use depthsense_train::bench::{bench_train, BenchTrainOptions};

#[derive(clap::Args)]
pub struct Args {
    /// Prepared data (default: a generated 800x350 toy dataset in a temporary directory).
    #[arg(long)]
    data: Option<PathBuf>,
    /// Model preset: paper, released or tiny.
    #[arg(long, default_value = "paper")]
    config: String,
    /// Batch size.
    #[arg(long, default_value_t = 8)]
    batch_size: usize,
    /// Timed training iterations (after the warm-up).
    #[arg(long, default_value_t = 3)]
    iterations: usize,
    /// Untimed warm-up iterations.
    #[arg(long, default_value_t = 1)]
    warmup: usize,
    /// Batches timed for the data loader alone.
    #[arg(long, default_value_t = 8)]
    loader_batches: usize,
    /// Device: auto, cpu, cuda or cuda:N.
    #[arg(long, default_value = "auto")]
    device: String,
    /// Data-loader threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    jobs: usize,
    /// bf16 autocast (CUDA only).
    #[arg(long)]
    amp: bool,
    /// Any model-config field as key=value (repeatable), e.g. `--set input-downscale=2`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Also write the JSON report to this file.
    #[arg(long)]
    out: Option<PathBuf>,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let opts = BenchTrainOptions {
        data: a.data,
        preset: a.config,
        batch_size: a.batch_size,
        iterations: a.iterations,
        warmup: a.warmup,
        loader_batches: a.loader_batches,
        device: a.device,
        jobs: a.jobs,
        amp: a.amp,
        set: a.set,
    };
    let pb = super::train::progress_bar("bench");
    let v = bench_train(&opts, &pb)?;
    pb.finish_and_clear();
    let text = serde_json::to_string_pretty(&v)?;
    if let Some(p) = &a.out {
        depthsense_nuscenes::fsutil::write_atomic(p, text.as_bytes())?;
    }
    println!("{text}");
    Ok(ExitCode::SUCCESS)
}
