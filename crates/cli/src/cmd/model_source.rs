//! The network a command runs, as `predict`, `export`, `explain` and `experiment
//! failure|perturb` take it: `--checkpoint`, `--config`,
//! `--set` (flattened into their arguments).

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ModelSource {
    /// Checkpoint written by `train`, or a PyTorch state dict such as the authors'
    /// paper_weights_rvmde.pth together with `--config released`.
    #[arg(long)]
    pub checkpoint: PathBuf,
    #[arg(long, value_parser = depthsense_config::cli::parse_config_spec,
          help = depthsense_config::cli::config_help("Architecture", ", a model-config JSON or an export sidecar (FILE.json \
                     of `export`). Required for a PyTorch .pth; for a depthsense checkpoint it \
                     replaces the stored config"))]
    pub config: Option<String>,
    #[arg(long = "set", value_name = "KEY=VALUE", value_parser = depthsense_config::cli::parse_set,
          help = crate::cmd::SET_HELP)]
    pub set: Vec<String>,
}
