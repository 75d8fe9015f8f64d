//! `depthsense demo`: synthetic world → prepare → train RGB-only and radar fusion → eval →
//! OUT/report/.

use std::path::PathBuf;
use std::process::ExitCode;

use depthsense_experiments::demo::{run_demo, DemoOptions};
use indicatif::MultiProgress;

#[derive(clap::Args)]
pub struct Args {
    /// Output directory (world/, prepared/, rgb/, fusion/, report/).
    #[arg(long, default_value = "runs/demo")]
    out: PathBuf,
    /// Device: auto (CUDA when available: more epochs and batch 8), cpu, cuda or cuda:N.
    #[arg(long, default_value = "auto")]
    device: String,
    /// A much smaller run (a few scenes, a few steps): checks the pipeline end to end.
    #[arg(long)]
    quick: bool,
    /// Seed of the world, initialisation and training (both models use the same).
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Override the number of training epochs of each model.
    #[arg(long)]
    epochs: Option<usize>,
    /// Override the number of scenes of the synthetic world (default 16 on a CPU).
    #[arg(long)]
    scenes: Option<usize>,
    /// Override the keyframes per scene of the synthetic world (default 10).
    #[arg(long)]
    keyframes_per_scene: Option<usize>,
    /// Worker threads of synth / prepare / loader (0 = all cores).
    #[arg(long, default_value_t = 0)]
    jobs: usize,
    /// Number of test samples drawn in the report.
    #[arg(long, default_value_t = 4)]
    pictures: usize,
    /// Replace a demo already in --out (its world, prepared data, runs and report); without
    /// it such a folder is refused.
    #[arg(long)]
    force: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let opts = DemoOptions {
        out: a.out,
        device: a.device,
        quick: a.quick,
        seed: a.seed,
        epochs: a.epochs,
        scenes: a.scenes,
        keyframes_per_scene: a.keyframes_per_scene,
        jobs: a.jobs,
        pictures: a.pictures,
        force: a.force,
        command_line: Some(std::env::args().collect::<Vec<_>>().join(" ")),
    };
    let mp = MultiProgress::new();
    let s = run_demo(&opts, &mp)?;
    println!(
        "{}",
        std::fs::read_to_string(s.report_dir.join("README.md"))?
    );
    eprintln!(
        "demo finished in {:.1} s: RGB-only RMSE {:.3} m, radar fusion RMSE {:.3} m; report in {} \
         (one page: {})",
        s.total_seconds,
        s.rgb_rmse,
        s.fusion_rmse,
        s.report_dir.display(),
        s.report_dir.join("report.html").display()
    );
    Ok(ExitCode::SUCCESS)
}
