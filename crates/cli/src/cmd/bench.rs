use std::process::ExitCode;

use clap::Subcommand;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    what: What,
}

#[derive(Subcommand)]
enum What {
    /// Data layer: table loading, prepare throughput, projection time.
    Data(super::bench_data::Args),
    /// Synthetic world generation throughput.
    Synth(super::bench_synth::Args),
    /// Network forward / training step time and memory.
    Model(super::bench_model::Args),
    /// Training and data-loader throughput.
    Train(super::bench_train::Args),
}

pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    match args.what {
        What::Data(a) => super::bench_data::run(a),
        What::Synth(a) => super::bench_synth::run(a),
        What::Model(a) => super::bench_model::run(a),
        What::Train(a) => super::bench_train::run(a),
    }
}
