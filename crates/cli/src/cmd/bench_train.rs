//! `depthsense bench train`: training images/s and data-loader images/s, as JSON.

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Prepared data (default: a generated 800x350 toy dataset in a temporary directory).
    #[arg(long)]
    pub data: Option<PathBuf>,
    #[arg(long, default_value = "paper", value_parser = depthsense_config::cli::parse_config_spec,
          help = depthsense_config::cli::config_help("Network", " or a model-config JSON"))]
    pub config: String,
    /// Batch size.
    #[arg(long, default_value_t = 8)]
    pub batch_size: usize,
    /// Timed training iterations (after the warm-up).
    #[arg(long, default_value_t = 3)]
    pub iterations: usize,
    /// Untimed warm-up iterations.
    #[arg(long, default_value_t = 1)]
    pub warmup: usize,
    /// Batches timed for the data loader alone.
    #[arg(long, default_value_t = 8)]
    pub loader_batches: usize,
    #[command(flatten)]
    pub device: crate::cmd::device_arg::DeviceArg,
    /// Data-loader threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub jobs: usize,
    /// bf16 autocast (CUDA only).
    #[arg(long)]
    pub amp: bool,
    #[arg(long = "set", value_name = "KEY=VALUE", value_parser = depthsense_config::cli::parse_set,
          help = crate::cmd::SET_SHORT, long_help = depthsense_config::cli::set_help())]
    pub set: Vec<String>,
    /// Also write the JSON report to this file.
    #[arg(long)]
    pub out: Option<PathBuf>,
}
