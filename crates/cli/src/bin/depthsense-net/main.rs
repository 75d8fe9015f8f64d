//! `depthsense-net`: every command of depthsense, linked with libtorch. Users call
//! `depthsense`, which runs the data commands without libtorch and hands the network commands
//! (train, eval --checkpoint, predict, export, …) to this binary; it parses the same command
//! line (`depthsense_cli::Cli`).

use std::process::ExitCode;

use depthsense_cli::{cmd, finish, run_without_torch, Command};

mod bench_export;
mod bench_model;
mod bench_train;
mod demo;
mod eval;
mod experiment;
mod explain;
mod export;
mod mer;
mod model_info;
mod model_source;
mod predict;
mod predict_frames;
mod train;

fn run_network(command: Command) -> anyhow::Result<ExitCode> {
    match command {
        Command::ModelInfo(a) => model_info::run(a),
        Command::Train(a) => train::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Predict(a) => predict::run(a),
        Command::Export(a) => export::run(a),
        Command::Demo(a) => demo::run(a),
        Command::Experiment(a) => experiment::run(a),
        Command::Explain(a) => explain::run(a),
        Command::Bench(cmd::bench::Args { what }) => match what {
            cmd::bench::What::Model(a) => bench_model::run(a),
            cmd::bench::What::Train(a) => bench_train::run(a),
            cmd::bench::What::Export(a) => bench_export::run(a),
            what => unreachable_data(Command::Bench(cmd::bench::Args { what })),
        },
        Command::Mer(a) => mer::run(a),
        other => unreachable_data(other),
    }
}

/// A data command reaching the network dispatch: `run_without_torch` took it first.
fn unreachable_data(_: Command) -> anyhow::Result<ExitCode> {
    anyhow::bail!("internal error: a data command reached depthsense-net's network dispatch")
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
    let cli = match depthsense_cli::parse() {
        Ok(cli) => cli,
        Err(e) => return finish(Err(e)),
    };
    depthsense_progress::configure(cli.log_every);
    finish(match run_without_torch(cli.command) {
        Ok(result) => result,
        Err(network_command) => run_network(*network_command),
    })
}
