//! The network a command runs, as `predict` and `export` take it: `--checkpoint`, `--config`,
//! `--set` (flattened into their arguments).

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ModelSource {
    /// Checkpoint written by `train`, or a PyTorch state dict such as the authors'
    /// paper_weights_rvmde.pth together with `--config released`.
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Architecture: a preset (paper, released, tiny), a model-config JSON or an export
    /// sidecar (FILE.json of `export`). Required for a PyTorch .pth; for a depthsense
    /// checkpoint it replaces the stored config.
    #[arg(long)]
    pub config: Option<String>,
    /// Override one config option, `key=value`, repeatable (keys as in `model-info --set`).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}
