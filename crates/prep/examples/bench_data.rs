//! The `depthsense bench data` benchmarks without the torch-linked CLI, so that a release
//! build needs only the data crates: `cargo run --release -p depthsense-prep --example
//! bench_data -- [OUT.json] [TABLES_SCALE]`.

use std::path::PathBuf;

use depthsense_prep::bench::{run_bench_data, BenchDataConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let out = PathBuf::from(
        args.first()
            .cloned()
            .unwrap_or_else(|| "bench-data.json".into()),
    );
    let scale: f64 = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(1.0);
    let cfg = BenchDataConfig {
        fixture: PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/fixtures/nuscenes-kf0"),
        tables_scale: scale,
        skip_tables: scale <= 0.0,
        samples: 40,
        lidar_k: vec![0, 10],
        jobs: 0,
        work: None,
    };
    let report = run_bench_data(&cfg)?;
    let text = serde_json::to_string_pretty(&report)?;
    std::fs::write(&out, &text)?;
    println!("{text}");
    Ok(())
}
