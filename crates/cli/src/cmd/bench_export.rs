//! `depthsense bench export`: the exported ONNX graph in onnxruntime (CPU) beside depthsense's
//! own forward + decode, same network, inputs, threads and machine, in one run — with the two
//! depth maps compared.

use std::path::PathBuf;

use crate::cmd::heading as h;

#[derive(clap::Args)]
pub struct Args {
    #[arg(long, help_heading = h::MODEL, alias = "preset", default_value = "tiny", value_parser = depthsense_config::cli::parse_config_spec,
          help = depthsense_config::cli::config_help("Network", " or a model-config JSON; random weights (seed 0), as `bench \
                     model` builds it"))]
    pub config: String,
    #[arg(long = "set", help_heading = h::MODEL, value_name = "KEY=VALUE", value_parser = depthsense_config::cli::parse_set,
          help = crate::cmd::SET_HELP)]
    pub set: Vec<String>,
    /// Images per run (the graph's batch axis is dynamic).
    #[arg(long, help_heading = h::TIMING, default_value_t = 1)]
    pub batch: usize,
    /// Untimed runs of each engine before the timed ones.
    #[arg(long, help_heading = h::TIMING, default_value_t = 3)]
    pub warmup_runs: usize,
    /// Timed runs of each engine; the median is reported.
    #[arg(long, help_heading = h::TIMING, default_value_t = 10)]
    pub repeats: usize,
    /// CPU threads of both engines (default: libtorch's choice, all cores).
    #[arg(long, help_heading = h::DEVICE)]
    pub threads: Option<usize>,
    /// The Python with onnxruntime (default: as `export --python`).
    #[arg(long, help_heading = h::DEVICE)]
    pub python: Option<PathBuf>,
    /// Write the results as JSON to this file.
    #[arg(long, help_heading = h::OUTPUT, value_name = "FILE")]
    pub out: Option<PathBuf>,
}
