//! `depthsense bench train`: training images/s and data-loader images/s, as JSON.

use std::path::PathBuf;

use crate::cmd::heading as h;

#[derive(clap::Args)]
pub struct Args {
    /// Prepared data (default: a generated 800x350 toy dataset in a temporary directory).
    #[arg(long, help_heading = h::DATA)]
    pub data: Option<PathBuf>,
    #[arg(long, help_heading = h::MODEL, default_value = "paper", value_parser = depthsense_config::cli::parse_config_spec,
          help = depthsense_config::cli::config_help("Network", " or a model-config JSON"))]
    pub config: String,
    /// Batch size.
    #[arg(long, help_heading = h::TIMING, default_value_t = 8)]
    pub batch_size: usize,
    /// Timed training iterations (after the warm-up).
    #[arg(long, help_heading = h::TIMING, default_value_t = 3)]
    pub iterations: usize,
    /// Untimed training iterations before the timed ones (cuDNN autotuning, first allocations).
    #[arg(long, help_heading = h::TIMING, default_value_t = 1)]
    pub warmup_runs: usize,
    /// Batches timed for the data loader alone.
    #[arg(long, help_heading = h::TIMING, default_value_t = 8)]
    pub loader_batches: usize,
    #[command(flatten, next_help_heading = h::DEVICE)]
    pub device: depthsense_config::device::DeviceArg,
    /// Data-loader threads (0 = all cores).
    #[arg(long, help_heading = h::DEVICE, default_value_t = 0)]
    pub jobs: usize,
    /// bf16 autocast (CUDA only).
    #[arg(long, help_heading = h::DEVICE)]
    pub amp: bool,
    #[arg(long = "set", help_heading = h::MODEL, value_name = "KEY=VALUE", value_parser = depthsense_config::cli::parse_set,
          help = crate::cmd::SET_HELP)]
    pub set: Vec<String>,
    /// Also write the JSON report to this file.
    #[arg(long, help_heading = h::OUTPUT)]
    pub out: Option<PathBuf>,
}
