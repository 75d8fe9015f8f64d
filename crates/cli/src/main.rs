//! `depthsense`: the thin command-line front of the depthsense libraries.
//! Each subcommand lives in `cmd/<name>.rs` with its `Args` and a `run` function.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cmd;

/// Metric depth for a car's front camera, fused with sparse automotive radar (DepthSense),
/// trained and evaluated on nuScenes or on the embedded synthetic world.
#[derive(Parser)]
#[command(name = "depthsense", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Turn a raw nuScenes dataroot into training-frame maps (800x350 PNGs + meta.json).
    Prepare(cmd::prepare::Args),
    /// Operations on prepared folders: `index merge` combines sharded preparation.
    Index(cmd::index::Args),
    /// Print a JSON summary of a sensor file (.pcd, .pcd.bin, .jpg) or a version folder.
    Inspect(cmd::inspect::Args),
    /// Generate the synthetic nuScenes-format world (the embedded default dataset).
    Synth(cmd::synth::Args),
    /// Print parameters per module and multiply-adds of a model configuration.
    ModelInfo(cmd::model_info::Args),
    /// Train a depth network on prepared data.
    Train(cmd::train::Args),
    /// Evaluate a checkpoint: the paper's tables as Markdown, CSV and JSON.
    Eval(cmd::eval::Args),
    /// Predict depth for a prepared sample, a sample token, or raw files.
    Predict(cmd::predict::Args),
    /// Synthesise a world, prepare, train, evaluate and write a report, end to end.
    Demo(cmd::demo::Args),
    /// Experiments of the paper built from training runs (ablation: variants × seeds).
    Experiment(cmd::experiment::Args),
    /// Grad-CAM++ maps by distance class (SPEC §10.6), with and without radar.
    Explain(cmd::explain::Args),
    /// Benchmarks that write a JSON report (tables, prepare, synth, model, train, loader).
    Bench(cmd::bench::Args),
    /// MER (multi-channel enhanced radar): train the radar–pixel association network, apply it
    /// to prepared data, report coverage and error.
    Mer(cmd::mer::Args),
    /// Gather every experiment output under some run folders into one self-contained HTML
    /// page (tables, plots, figure grids, the commands that made them), plus Markdown and JSON.
    Report(cmd::report::Args),
}

fn run() -> anyhow::Result<ExitCode> {
    let cli = Cli::parse();
    match cli.command {
        Command::Prepare(a) => cmd::prepare::run(a),
        Command::Index(a) => cmd::index::run(a),
        Command::Inspect(a) => cmd::inspect::run(a),
        Command::Synth(a) => cmd::synth::run(a),
        Command::ModelInfo(a) => cmd::model_info::run(a),
        Command::Train(a) => cmd::train::run(a),
        Command::Eval(a) => cmd::eval::run(a),
        Command::Predict(a) => cmd::predict::run(a),
        Command::Demo(a) => cmd::demo::run(a),
        Command::Experiment(a) => cmd::experiment::run(a),
        Command::Explain(a) => cmd::explain::run(a),
        Command::Bench(a) => cmd::bench::run(a),
        Command::Mer(a) => cmd::mer::run(a),
        Command::Report(a) => cmd::report::run(a),
    }
}

fn main() -> ExitCode {
    match run() {
        Ok(code) => code,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
