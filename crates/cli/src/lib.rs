//! The command line of depthsense, shared by its two binaries (ARCHITECTURE.md, "cli"):
//!
//! - `depthsense` (src/main.rs) never links libtorch: it parses every command, runs the ones
//!   that need no network (synth, prepare, inspect, index, bench data|synth, …) and hands the
//!   others to `depthsense-net` beside it (exec: same process id, arguments, environment);
//! - `depthsense-net` (src/bin/depthsense-net/) links libtorch and runs every command.
//!
//! Each subcommand's flags live in `cmd/<name>.rs` (`Args`); a data command's `run` sits
//! beside them, a network command's in `src/bin/depthsense-net/<name>.rs`.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

pub mod cmd;
pub mod handoff;
#[cfg(test)]
mod newcomer;
pub mod preflight;
pub mod stop;

/// Metric depth for a car's front camera, fused with sparse automotive radar (DepthSense),
/// trained and evaluated on nuScenes or on the embedded synthetic world.
#[derive(Parser)]
#[command(name = "depthsense", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
    /// When stderr is not a terminal (`> run.log 2>&1`, Slurm, nohup, CI), long commands print
    /// a plain progress line this often: seconds (`30s`, `2m`) or steps (`100it`: iterations,
    /// keyframes, samples). On a terminal the progress bars stay. `DEPTHSENSE_PROGRESS=bars|
    /// lines|none` overrides the choice.
    #[arg(long, global = true, default_value = "30s", value_name = "EVERY")]
    pub log_every: depthsense_progress::LogEvery,
}

#[derive(Subcommand)]
pub enum Command {
    /// Turn a raw nuScenes dataroot into training-frame maps (800x350 PNGs + meta.json).
    Prepare(cmd::prepare::Args),
    /// Operations on prepared folders: `index merge` combines sharded preparation.
    Index(cmd::index::Args),
    /// Print a JSON summary of sensor files (.pcd, .pcd.bin, .jpg), folders of them, or a
    /// version folder.
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
    /// Write the calibration JSON of `predict --image` for a sample of a dataroot (the camera
    /// and every radar sweep prepare reads, with their transforms).
    Calibration(cmd::calibration::Args),
    /// A trained network as ONNX, TorchScript or a PyTorch state dict, with a sidecar JSON.
    Export(cmd::export::Args),
    /// Synthesise a world, prepare, train, evaluate and write a report, end to end.
    Demo(cmd::demo::Args),
    /// Experiments of the paper built from training runs (ablation: variants × seeds).
    Experiment(cmd::experiment::Args),
    /// Grad-CAM++ maps by distance class (SPEC §10.6), with and without radar.
    Explain(cmd::explain::Args),
    /// Benchmarks that write a JSON report (tables, prepare, synth, model, train, loader, onnxruntime).
    Bench(cmd::bench::Args),
    /// MER (multi-channel enhanced radar): train the radar–pixel association network, apply it
    /// to prepared data, report coverage and error.
    Mer(cmd::mer::Args),
    /// Gather every experiment output under some run folders into one self-contained HTML
    /// page (tables, plots, figure grids, the commands that made them), plus Markdown and JSON.
    Report(cmd::report::Args),
    /// The command-line reference as Markdown (docs/guide/cli.md).
    #[command(hide = true)]
    HelpMarkdown(cmd::help_markdown::Args),
}

/// Parses this process's command line (clap's own errors and `--help` exit as clap does),
/// then refuses what must be refused before any work ([`preflight`]: outputs that cannot be
/// written, flag combinations that need a word of advice).
pub fn parse() -> anyhow::Result<Cli> {
    use clap::{CommandFactory, FromArgMatches};
    let matches = Cli::command().get_matches();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    preflight::check(&matches)?;
    Ok(cli)
}

/// Runs `command` in this process when it needs no network, i.e. without libtorch; gives it
/// back (`Err`) when it does.
pub fn run_without_torch(command: Command) -> Result<anyhow::Result<ExitCode>, Box<Command>> {
    match command {
        Command::Prepare(a) => Ok(cmd::prepare::run(a)),
        Command::Index(a) => Ok(cmd::index::run(a)),
        Command::Inspect(a) => Ok(cmd::inspect::run(a)),
        Command::Synth(a) => Ok(cmd::synth::run(a)),
        Command::Calibration(a) => Ok(cmd::calibration::run(a)),
        Command::Report(a) => Ok(cmd::report::run(a)),
        Command::HelpMarkdown(a) => Ok(cmd::help_markdown::run(a)),
        Command::ModelInfo(a) if a.keys => Ok(cmd::model_info::print_keys()),
        Command::Eval(a) => match a.predictions.clone() {
            Some(dir) => Ok(cmd::eval::run_predictions(a, dir)),
            None => Err(Box::new(Command::Eval(a))),
        },
        Command::Mer(cmd::mer::Args { command }) => match command {
            cmd::mer::Command::Report(a) => Ok(cmd::mer::run_report(a)),
            command => Err(Box::new(Command::Mer(cmd::mer::Args { command }))),
        },
        Command::Bench(cmd::bench::Args { what }) => match what {
            cmd::bench::What::Data(a) => Ok(cmd::bench_data::run(a)),
            cmd::bench::What::Synth(a) => Ok(cmd::bench_synth::run(a)),
            what => Err(Box::new(Command::Bench(cmd::bench::Args { what }))),
        },
        other => Err(Box::new(other)),
    }
}

/// The invocation as the user typed it (`depthsense …`: the handoff keeps argv[0]), recorded
/// in the outputs that name the command that made them (tables.json, reports, experiments).
pub fn command_line() -> String {
    std::env::args().collect::<Vec<_>>().join(" ")
}

/// How both binaries end: the command's exit code, or its error on stderr and exit code 1.
pub fn finish(result: anyhow::Result<ExitCode>) -> ExitCode {
    match result {
        Ok(code) => code,
        Err(err) => {
            eprintln!("error: {}", error_text(&err));
            ExitCode::FAILURE
        }
    }
}

/// An error and its causes, each said once: a cause whose text the message already holds
/// (`path: No such file or directory` with the `io::Error` as its source) is not repeated.
pub fn error_text(err: &anyhow::Error) -> String {
    let mut text = err.to_string();
    for cause in err.chain().skip(1) {
        let c = cause.to_string();
        if !text.contains(&c) {
            text.push_str(": ");
            text.push_str(&c);
        }
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_error_says_each_cause_once() {
        #[derive(Debug, thiserror::Error)]
        #[error("runs/x/index.json: {source}")]
        struct Io {
            #[source]
            source: std::io::Error,
        }
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "No such file");
        let e = anyhow::Error::new(Io { source: io });
        assert_eq!(error_text(&e), "runs/x/index.json: No such file");
        let e = e.context("reading the index");
        assert_eq!(
            error_text(&e),
            "reading the index: runs/x/index.json: No such file"
        );
    }
}
