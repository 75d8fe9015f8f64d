//! `depthsense bench train`: training images/s and data-loader images/s, as JSON. (the network side; its flags: `depthsense_cli::cmd::bench_train`).

use depthsense_cli::cmd::bench_train::Args;
use depthsense_cli::cmd::progress::progress_bar;
use depthsense_train::bench::{bench_train, BenchTrainOptions};
use std::process::ExitCode;

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let opts = BenchTrainOptions {
        data: a.data,
        preset: a.config,
        batch_size: a.batch_size,
        iterations: a.iterations,
        warmup: a.warmup_runs,
        loader_batches: a.loader_batches,
        device: a.device.name,
        jobs: a.jobs,
        amp: a.amp,
        set: a.set,
    };
    let pb = progress_bar("bench");
    let v = bench_train(&opts, &pb)?;
    pb.finish_and_clear();
    let text = serde_json::to_string_pretty(&v)?;
    if let Some(p) = &a.out {
        depthsense_base::fsutil::write_atomic(p, text.as_bytes())?;
    }
    println!("{text}");
    Ok(ExitCode::SUCCESS)
}
