//! `depthsense model-info`: parameters per module and multiply-adds at 350x800.

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Network: a preset (paper, released, tiny), a model-config JSON file, or a depthsense
    /// checkpoint (.safetensors; its stored config is used).
    #[arg(long, default_value = "paper")]
    pub config: String,
    /// Override one config option, `key=value`, repeatable (e.g. `--set backbone=50
    /// --set fusion=early --set attention=off --set head=l1 --set radar-channels=7`). Keys:
    /// backbone (18|34|50|101), width, fusion (late|early|none), attention (on|off),
    /// head (ordinal|l1|l2), radar-channels (1|7), radar-branch (basic|bottleneck),
    /// radar-width, radar-out-channels, decoder (topdown|released), decoder-channels,
    /// stem (torchvision|deep), head-channels, head-pre-dropout, dropout, bins, alpha, beta,
    /// decode-offset (m), align-corners (on|off), out-height, out-width.
    #[arg(long = "set", value_name = "KEY=VALUE")]
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
}
