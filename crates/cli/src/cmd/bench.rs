//! `depthsense bench data | synth | model | train | export`: benchmarks that write a JSON report.

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub what: What,
}

#[derive(clap::Subcommand)]
pub enum What {
    /// Data layer: table loading, prepare throughput, projection time.
    Data(super::bench_data::Args),
    /// Synthetic world generation throughput.
    Synth(super::bench_synth::Args),
    /// Network forward / training step time and memory.
    Model(super::bench_model::Args),
    /// Training and data-loader throughput.
    Train(super::bench_train::Args),
    /// The exported ONNX graph in onnxruntime (CPU) beside depthsense's own forward.
    Export(super::bench_export::Args),
}
