//! `depthsense train`: train a depth network on prepared data (SPEC §8).

use std::path::PathBuf;

use crate::cmd::heading as h;

/// `train --help`'s examples (each parsed by the docs test through docs/guide/cli.md).
const EXAMPLES: &str = "Examples:
  depthsense train --data prepared --config tiny --epochs 5 --out runs/tiny
  depthsense train --data prepared --out runs/paper --backbone-weights resnet101-63fe2227.pth
  depthsense train --data prepared --out runs/paper --resume
  depthsense train --data prepared --out runs/paper --nproc 2 --sync-bn --batch-size 16
(docs/guide/train.md: presets, weights, resuming, data-parallel runs)";

#[derive(clap::Args)]
#[command(after_help = EXAMPLES)]
pub struct Args {
    /// Prepared data directory (output of `depthsense prepare`, holds index.json).
    #[arg(long, help_heading = h::DATA)]
    pub data: PathBuf,
    #[arg(long, help_heading = h::MODEL, default_value = "paper", value_parser = depthsense_config::cli::parse_config_spec,
          help = depthsense_config::cli::config_help("Network", ", a model-config JSON or an export sidecar"))]
    pub config: String,
    /// Run directory: config.json, metrics.jsonl, curves.png, last/best checkpoints.
    #[arg(long, help_heading = h::OUTPUT, default_value = "runs/train")]
    pub out: PathBuf,
    #[arg(long, help_heading = h::MODEL, value_parser = depthsense_config::cli::parse_value("fusion"),
          help = depthsense_config::cli::value_help("fusion", "Override the preset's fusion \
                 (none = rgb = RGB only; not late: no attention)"))]
    pub fusion: Option<String>,
    #[arg(long, help_heading = h::MODEL, value_parser = depthsense_config::cli::parse_value("head"),
          help = depthsense_config::cli::value_help("head", "Override the preset's head"))]
    pub head: Option<String>,
    /// Override the preset's Dropout2d probability in the head (paper: 0.5).
    #[arg(long, help_heading = h::MODEL, value_parser = crate::cmd::ranges::probability, allow_negative_numbers = true)]
    pub dropout: Option<f64>,
    /// Disable the spatial attention module of late fusion.
    #[arg(long, help_heading = h::MODEL)]
    pub no_attention: bool,
    #[arg(long = "set", help_heading = h::MODEL, value_name = "KEY=VALUE", value_parser = depthsense_config::cli::parse_set,
          help = crate::cmd::SET_HELP)]
    pub set: Vec<String>,
    #[command(flatten)]
    pub schedule: depthsense_config::training::ScheduleOptions,
    #[command(flatten)]
    pub loading: depthsense_config::training::LoadingOptions,
    #[command(flatten)]
    pub validation: depthsense_config::training::ValidationOptions,
    #[command(flatten)]
    pub checkpointing: depthsense_config::training::CheckpointOptions,
    #[command(flatten)]
    pub extension: depthsense_config::training::ExtendOptions,
    #[command(flatten)]
    pub hardware: depthsense_config::training::HardwareOptions,
    #[command(flatten)]
    pub distributed: depthsense_config::training::DistributedOptions,
    /// torchvision ResNet state dict to initialise the RGB encoder: ImageNet weights such as
    /// torchvision's resnet101-63fe2227.pth (docs/guide/train.md, "Weights" says where they
    /// come from and which layouts are read).
    #[arg(long, help_heading = h::MODEL)]
    pub backbone_weights: Option<PathBuf>,
    /// Fine-tune: start the fresh network from these weights — a depthsense checkpoint
    /// (RUN/best.safetensors), an `export --format pytorch` .pth, or the authors' .pth with
    /// `--config released`. Prints (and config.json records) which tensors were loaded and
    /// which are new; the run's own schedule starts at iteration 0.
    #[arg(long, help_heading = h::MODEL, value_name = "CHECKPOINT", conflicts_with_all = ["resume", "extend"])]
    pub init_from: Option<PathBuf>,
    /// Radar map(s) for the radar channels: height, raw, raw-height or mer (raw + 6 MER
    /// channels, after `depthsense mer apply`; sets radar_channels = 7). Default: from the
    /// model's radar_channels (1 → height, 2 → raw-height, 7 → mer). Stored in the
    /// checkpoint's model config: `eval` and `predict` feed the same input.
    #[arg(long, help_heading = h::DATA, value_parser = depthsense_config::cli::parse_value("radar-input"))]
    pub radar_input: Option<String>,
    /// Withhold a fraction of one condition's TRAINING scenes (SPEC §10.5), e.g.
    /// `night=1.0,rain=0.5`: per condition, its training scenes ordered by a fixed hash of
    /// the scene name, the first round(fraction × n) withheld (docs/guide/experiments.md,
    /// "Reduced training data"). Validation and test scenes are unchanged.
    #[arg(long, help_heading = h::DATA, value_delimiter = ',', value_name = "CONDITION=FRACTION")]
    pub exclude: Vec<String>,
    /// Validation's scoring (the same flags as `eval`).
    #[command(flatten, next_help_heading = h::VALIDATION)]
    pub scoring: crate::cmd::scoring_args::ScoringArgs,
}

/// The note of a bare `train` (no `--config` among `words`) on a machine without CUDA. The
/// default stays `paper` everywhere: the same command trains the same network on a laptop and
/// on the cluster, so a result never depends on where it ran; the note names the network and
/// the preset for a CPU, and the run's `pace:` line says within a few iterations how long an
/// epoch takes.
pub fn default_network_note(words: &[String], cuda: bool) -> Option<String> {
    let config_given = words
        .iter()
        .any(|a| a == "--config" || a.starts_with("--config="));
    (!config_given && !cuda).then(|| {
        "note: no --config: training `paper`, the paper's network (57 M parameters), without \
         CUDA, where an epoch of nuScenes takes many hours (the `pace:` line below measures \
         it); `--config tiny` (0.9 M parameters) is the preset for a CPU"
            .to_string()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bare_train_without_cuda_names_its_network() {
        let w = |s: &str| s.split(' ').map(String::from).collect::<Vec<_>>();
        let note = default_network_note(&w("depthsense train --data p"), false).unwrap();
        assert!(
            note.contains("`paper`") && note.contains("--config tiny"),
            "{note}"
        );
        assert_eq!(
            default_network_note(&w("depthsense train --data p"), true),
            None
        );
        assert_eq!(
            default_network_note(&w("depthsense train --data p --config=tiny"), false),
            None
        );
        assert_eq!(
            default_network_note(&w("depthsense train --config paper"), false),
            None
        );
    }
}
