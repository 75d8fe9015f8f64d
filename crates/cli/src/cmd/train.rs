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
    /// Epochs (paper: 40).
    #[arg(long, help_heading = h::SCHEDULE, default_value_t = 40, value_parser = crate::cmd::ranges::count, allow_negative_numbers = true)]
    pub epochs: usize,
    /// Batch size (paper: 8).
    #[arg(long, help_heading = h::SCHEDULE, default_value_t = 8, value_parser = crate::cmd::ranges::count, allow_negative_numbers = true)]
    pub batch_size: usize,
    /// Initial learning rate (paper: 1e-3).
    #[arg(long, help_heading = h::SCHEDULE, default_value_t = 1e-3, value_parser = crate::cmd::ranges::positive, allow_negative_numbers = true)]
    pub lr: f64,
    /// Power of the per-iteration polynomial decay to 0 (paper: 0.9).
    #[arg(long, help_heading = h::SCHEDULE, default_value_t = 0.9, value_parser = crate::cmd::ranges::non_negative, allow_negative_numbers = true)]
    pub lr_power: f64,
    /// SGD momentum (paper: 0.9).
    #[arg(long, help_heading = h::SCHEDULE, default_value_t = 0.9, value_parser = crate::cmd::ranges::probability, allow_negative_numbers = true)]
    pub momentum: f64,
    /// Weight decay (paper: 1e-4).
    #[arg(long, help_heading = h::SCHEDULE, default_value_t = 1e-4, value_parser = crate::cmd::ranges::non_negative, allow_negative_numbers = true)]
    pub weight_decay: f64,
    /// Seed of initialisation, shuffling, augmentation and dropout.
    #[arg(long, help_heading = h::SCHEDULE, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten, next_help_heading = h::DEVICE)]
    pub device: crate::cmd::device_arg::DeviceArg,
    /// Mixed precision (bf16 autocast of the forward pass; CUDA only, ignored on CPU).
    #[arg(long, help_heading = h::DEVICE)]
    pub amp: bool,
    /// torchvision ResNet state dict to initialise the RGB encoder: ImageNet weights such as
    /// torchvision's resnet101-63fe2227.pth (docs/guide/train.md, "Weights" says where they
    /// come from and which layouts are read).
    #[arg(long, help_heading = h::MODEL)]
    pub backbone_weights: Option<PathBuf>,
    /// Fine-tune: start the fresh network from these weights — a depthsense checkpoint
    /// (RUN/best.safetensors), an `export --format pytorch` .pth, or the authors' .pth with
    /// `--config released`. Prints (and config.json records) which tensors were loaded and
    /// which are new; the run's own schedule starts at iteration 0.
    #[arg(long, help_heading = h::MODEL, value_name = "CHECKPOINT", conflicts_with = "resume")]
    pub init_from: Option<PathBuf>,
    /// Continue exactly from OUT/last.safetensors (same options required). A finished run is
    /// reported as finished (exit status 0); train it longer with --extend.
    #[arg(long, help_heading = h::OUTPUT)]
    pub resume: bool,
    /// Train the run in OUT longer: continue from OUT/last.safetensors to --epochs (more than
    /// it had) with a new learning-rate schedule from there (poly decay from --lr to 0 at the
    /// new end; the same batch size and seed). config.json records every schedule segment.
    #[arg(long, help_heading = h::OUTPUT, conflicts_with_all = ["force", "init_from"])]
    pub extend: bool,
    /// Start over in an --out that holds a run: its config.json, metrics.jsonl, curves.png and
    /// checkpoints are removed first (other files stay). Without --resume or --force such a
    /// folder is refused.
    #[arg(long, help_heading = h::OUTPUT, conflicts_with = "resume")]
    pub force: bool,
    /// Data-loader threads (0 = all cores).
    #[arg(long, help_heading = h::DATA, default_value_t = 0, value_parser = crate::cmd::ranges::non_negative_usize, allow_negative_numbers = true)]
    pub jobs: usize,
    /// Batches decoded ahead of the training step.
    #[arg(long, help_heading = h::DATA, default_value_t = 4, value_parser = crate::cmd::ranges::count, allow_negative_numbers = true)]
    pub prefetch: usize,
    /// Radar map(s) for the radar channels: height, raw, raw-height or mer (raw + 6 MER
    /// channels, after `depthsense mer apply`; sets radar_channels = 7). Default: from the
    /// model's radar_channels (1 → height, 2 → raw-height, 7 → mer). Stored in the
    /// checkpoint's model config: `eval` and `predict` feed the same input.
    #[arg(long, help_heading = h::DATA, value_parser = depthsense_config::cli::parse_value("radar-input"))]
    pub radar_input: Option<String>,
    /// Training target: dense (±K accumulated lidar) or sparse (keyframe sweep).
    #[arg(long, help_heading = h::DATA, default_value = "dense",
          value_parser = crate::cmd::words::words::<depthsense_data::TargetKind>())]
    pub target: depthsense_data::TargetKind,
    /// Disable flip and brightness/colour/gamma jitter.
    #[arg(long, help_heading = h::DATA)]
    pub no_augment: bool,
    /// Training-time radar dropout (not in the paper): each training sample loses a fraction
    /// U(0, P) of its radar returns with their height-extended strips, so that the network
    /// cannot read "no return here" as a depth cue. 0 = off. docs/guide/train.md.
    #[arg(long, help_heading = h::DATA, default_value_t = 0.0, value_name = "P", value_parser = crate::cmd::ranges::probability, allow_negative_numbers = true)]
    pub train_radar_drop: f64,
    /// The oracle radar (an upper bound, not a model): every radar return keeps its pixel but
    /// takes the lidar target's depth there (or the nearest valid target pixel within 3 px;
    /// returns without one are dropped), strips redrawn as SPEC §5 draws them; in training and
    /// validation. Needs radar_points.bin (prepare writes it). docs/guide/experiments.md.
    #[arg(long, help_heading = h::DATA)]
    pub radar_oracle: bool,
    /// Linear learning-rate warmup over the first N iterations, then the poly decay (0 = none,
    /// the paper).
    #[arg(long, help_heading = h::SCHEDULE, default_value_t = 0, value_name = "N", value_parser = crate::cmd::ranges::non_negative_u64, allow_negative_numbers = true)]
    pub warmup: u64,
    /// Only for data prepared without validation lists: every N-th training scene (sorted by
    /// name) is held out for validation (and, without any split lists, every N-th scene is
    /// test and the one before it validation). Never selects on test scenes.
    #[arg(long, help_heading = h::VALIDATION, default_value_t = 5, value_parser = crate::cmd::ranges::count, allow_negative_numbers = true)]
    pub val_every_scene: usize,
    /// Withhold a fraction of one condition's TRAINING scenes (SPEC §10.5), e.g.
    /// `night=1.0,rain=0.5`: per condition, its training scenes ordered by a fixed hash of
    /// the scene name, the first round(fraction × n) withheld (docs/guide/experiments.md,
    /// "Reduced training data"). Validation and test scenes are unchanged.
    #[arg(long, help_heading = h::DATA, value_delimiter = ',', value_name = "CONDITION=FRACTION")]
    pub exclude: Vec<String>,
    /// Train on the first N training samples only, in a fixed order of the samples (nested for
    /// growing N, the same for every seed): training-set size experiments. Validation and test
    /// scenes are unchanged.
    #[arg(long, help_heading = h::DATA, value_name = "N", value_parser = crate::cmd::ranges::count, allow_negative_numbers = true)]
    pub train_subset: Option<usize>,
    /// Make each epoch N iterations drawn from consecutive passes over the training samples
    /// (each pass a fresh shuffle), whatever their number: runs on 100 or 3,000 images then take
    /// --epochs × N iterations and validate every N. Default: an epoch is one pass.
    #[arg(long, help_heading = h::SCHEDULE, value_name = "N", value_parser = crate::cmd::ranges::count_u64, allow_negative_numbers = true)]
    pub epoch_iterations: Option<u64>,
    /// Validate on at most this many validation samples (evenly spaced).
    #[arg(long, help_heading = h::VALIDATION, value_parser = crate::cmd::ranges::count, allow_negative_numbers = true)]
    pub max_val_samples: Option<usize>,
    /// Train on at most this many batches per epoch (quick runs).
    #[arg(long, help_heading = h::SCHEDULE, value_parser = crate::cmd::ranges::count, allow_negative_numbers = true)]
    pub max_batches_per_epoch: Option<usize>,
    /// Also write OUT/last.safetensors every N iterations (0 = only at epoch ends).
    #[arg(long, help_heading = h::OUTPUT, default_value_t = 0, value_parser = crate::cmd::ranges::non_negative_u64, allow_negative_numbers = true)]
    pub checkpoint_every: u64,
    /// Read the training loss to the host every N iterations (one GPU synchronisation per N;
    /// always before checkpoints and at epoch ends). 0 = 1 on the CPU, 25 on CUDA.
    #[arg(long, help_heading = h::DEVICE, default_value_t = 0, value_name = "N", value_parser = crate::cmd::ranges::non_negative_u64, allow_negative_numbers = true)]
    pub loss_read_every: u64,
    /// Stop after this global iteration (checkpointed; continue with --resume).
    #[arg(long, help_heading = h::SCHEDULE, value_parser = crate::cmd::ranges::count_u64, allow_negative_numbers = true)]
    pub stop_after: Option<u64>,
    /// Validation's scoring (the same flags as `eval`).
    #[command(flatten, next_help_heading = h::VALIDATION)]
    pub scoring: crate::cmd::scoring_args::ScoringArgs,
    /// Data-parallel: start N local worker processes (one per GPU, or N CPU processes) with
    /// the environment torchrun sets. --batch-size is the global batch (a multiple of N).
    /// Under torchrun / srun leave this out: the workers read RANK, WORLD_SIZE, … themselves.
    #[arg(long, help_heading = h::DISTRIBUTED, value_name = "N", value_parser = crate::cmd::ranges::count, allow_negative_numbers = true)]
    pub nproc: Option<usize>,
    /// With --nproc: the rendezvous port on 127.0.0.1 (default: a free one).
    #[arg(long, help_heading = h::DISTRIBUTED)]
    pub master_port: Option<u16>,
    /// Data-parallel: SyncBatchNorm (batch statistics over the global batch), so N ranks
    /// train as one process with the same global batch.
    #[arg(long, help_heading = h::DISTRIBUTED)]
    pub sync_bn: bool,
    /// Data-parallel: seconds before a rendezvous or collective fails (naming the peer).
    #[arg(long, help_heading = h::DISTRIBUTED, default_value_t = 300, value_parser = crate::cmd::ranges::count_u64, allow_negative_numbers = true)]
    pub dist_timeout: u64,
    /// Data-parallel: gradient all-reduce bucket size in MB (DDP's default 25).
    #[arg(long, help_heading = h::DISTRIBUTED, default_value_t = 25.0, value_parser = crate::cmd::ranges::positive, allow_negative_numbers = true)]
    pub bucket_mb: f64,
    /// Data-parallel: after every step check that each rank's model equals rank 0's
    /// (bitwise; one broadcast of the model per step — for tests and debugging).
    #[arg(long, help_heading = h::DISTRIBUTED)]
    pub check_replicas: bool,
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
