//! `depthsense bench data`: table loading, prepare throughput and projection time.

use std::path::PathBuf;
use std::process::ExitCode;

use depthsense_prep::bench::{run_bench_data, BenchDataConfig};

#[derive(clap::Args)]
pub struct Args {
    /// Where the JSON report is written (also printed).
    #[arg(long, default_value = "bench-data.json")]
    out: PathBuf,
    /// The real keyframe fixture (nuscenes-kf0) the prepare/projection benchmarks build on.
    #[arg(long, default_value = "../shared/fixtures/nuscenes-kf0")]
    fixture: PathBuf,
    /// Scale of the generated tables relative to v1.0-trainval (1.0 ≈ 2.6 M sample_data rows).
    #[arg(long, default_value_t = 1.0)]
    tables_scale: f64,
    /// Skip the table-loading benchmark (it writes ~2.5 GB of JSON to a temp dir).
    #[arg(long)]
    skip_tables: bool,
    /// Keyframes of the generated world for the prepare benchmark.
    #[arg(long, default_value_t = 40)]
    samples: usize,
    /// Lidar sweeps per K setting, comma-separated (dense target ±K).
    #[arg(long, value_delimiter = ',', default_value = "0,10")]
    lidar_k: Vec<usize>,
    /// Worker threads for prepare (0 = all cores).
    #[arg(long, default_value_t = 0)]
    jobs: usize,
    /// Scratch directory (default: the system temp dir); removed afterwards.
    #[arg(long)]
    work: Option<PathBuf>,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let cfg = BenchDataConfig {
        fixture: a.fixture,
        tables_scale: a.tables_scale,
        skip_tables: a.skip_tables,
        samples: a.samples,
        lidar_k: a.lidar_k,
        jobs: a.jobs,
        work: a.work,
    };
    let report = run_bench_data(&cfg)?;
    let text = serde_json::to_string_pretty(&report)?;
    depthsense_base::fsutil::write_atomic(&a.out, text.as_bytes())?;
    println!("{text}");
    Ok(ExitCode::SUCCESS)
}
