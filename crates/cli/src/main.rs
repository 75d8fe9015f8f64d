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
    /// A trained network as ONNX, TorchScript or a PyTorch state dict, with a sidecar JSON.
    Export(cmd::export::Args),
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
        Command::Export(a) => cmd::export::run(a),
        Command::Demo(a) => cmd::demo::run(a),
        Command::Experiment(a) => cmd::experiment::run(a),
        Command::Explain(a) => cmd::explain::run(a),
        Command::Bench(a) => cmd::bench::run(a),
        Command::Mer(a) => cmd::mer::run(a),
        Command::Report(a) => cmd::report::run(a),
    }
}

/// libtorch allocates and frees several-MB tensors in every layer; by default glibc hands each
/// one back to the kernel (mmap above a threshold, heap trimming), so every forward and
/// backward pass page-faults its memory in again, 4 kB at a time. Measured on 2 cores
/// (BENCHMARKS.md, "Allocator"): 22 % of `mer apply`'s CPU time was the kernel faulting in
/// zeroed pages, and a third of a demo training epoch's. Two settings, before any tensor
/// exists:
/// - glibc keeps freed memory in the process: allocations up to 32 MB (glibc's ceiling for
///   this setting) come from the heap, which is trimmed only above 1 GB free;
/// - libtorch's CPU allocator aligns tensors of 2 MB and more to 2 MB and asks for transparent
///   huge pages (its own `THP_MEM_ALLOC_ENABLE`; a user's setting is kept), so the larger
///   tensors, which glibc always maps afresh, fault in 2 MB at a time.
fn tune_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator parameters; called before any other thread starts.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
    }
    if std::env::var_os("THP_MEM_ALLOC_ENABLE").is_none() {
        // Still single-threaded here; libtorch reads it at its first large allocation.
        std::env::set_var("THP_MEM_ALLOC_ENABLE", "1");
    }
}

fn main() -> ExitCode {
    tune_memory();
    match run() {
        Ok(code) => code,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
