//! `depthsense model-info`: parameters per module and multiply-adds at 350x800.

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[arg(long, default_value = "paper", value_parser = depthsense_config::cli::parse_config_spec,
          help = depthsense_config::cli::config_help("Network", ", a model-config JSON, an export sidecar or a depthsense \
                     checkpoint (.safetensors: its stored config)"))]
    pub config: String,
    #[arg(long = "set", value_name = "KEY=VALUE", value_parser = depthsense_config::cli::parse_set,
          help = crate::cmd::SET_HELP)]
    pub set: Vec<String>,
    /// Input height the multiply-adds are counted at.
    #[arg(long, default_value_t = 350)]
    pub height: i64,
    /// Input width the multiply-adds are counted at.
    #[arg(long, default_value_t = 800)]
    pub width: i64,
    /// Also write the report (and the resolved config) as JSON to this file.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Print the resolved config as JSON before the table.
    #[arg(long)]
    pub print_config: bool,
    /// Print every `--set` key with its values (and nothing else): the one list, from the
    /// registry every command reads.
    #[arg(long)]
    pub keys: bool,
}

/// `model-info --keys`: every `--set` key with its values (torch-free: `depthsense` runs it
/// itself).
pub fn print_keys() -> anyhow::Result<std::process::ExitCode> {
    println!("{}", depthsense_config::cli::set_help());
    Ok(std::process::ExitCode::SUCCESS)
}
