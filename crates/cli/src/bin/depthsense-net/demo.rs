//! `depthsense demo`: synthetic world → prepare → train RGB-only and radar fusion → eval → (the network side; its flags: `depthsense_cli::cmd::demo`).

use depthsense_cli::cmd::demo::Args;
use depthsense_experiments::demo::{run_demo, DemoOptions};
use depthsense_progress::Board;
use std::process::ExitCode;

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
        command_line: Some(depthsense_cli::command_line()),
    };
    let mp = Board::new(10);
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
