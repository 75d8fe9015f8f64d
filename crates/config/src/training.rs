//! The option groups of training, each defined once — its flags, their help, ranges and
//! defaults — and used as they are by every layer: the command line flattens them into
//! `train`'s arguments (`#[command(flatten)]`), `depthsense_train::trainer::TrainOptions` holds
//! them (`#[serde(flatten)]`: RUN/config.json's `"train"` keeps its flat keys), and their
//! `Default` is what the command line gives when a flag is left out ([`defaults`]), so a default
//! is written in one place, the flag's attribute.
//!
//! | group | heading | what |
//! |---|---|---|
//! | [`ScheduleOptions`] | Schedule | epochs, batches, learning rate and its decay, seed |
//! | [`LoadingOptions`] | Data | loader threads, target, augmentation, radar dropout, subsets |
//! | [`ValidationOptions`] | Validation | the validation samples |
//! | [`CheckpointOptions`] | Output | checkpoint cadence, stop, resume, force (`train`, `mer train`) |
//! | [`ExtendOptions`] | Output | `--extend` (`train`) |
//! | [`HardwareOptions`] | Device | device, mixed precision, loss reads |
//! | [`DistributedOptions`] | Data-parallel | local workers, SyncBatchNorm, all-reduce buckets |

use serde::{Deserialize, Serialize};

use crate::device::DeviceArg;
use crate::heading as h;
use crate::ranges;
use crate::words_parser::words;

/// serde `skip_serializing_if` for optional settings that are off at their default (0, false,
/// empty): the JSON of runs that do not use them stays as it was before they existed.
pub fn is_default<T: Default + PartialEq>(v: &T) -> bool {
    *v == T::default()
}

/// A group's values when none of its flags is given: the defaults of its flags' attributes.
pub fn defaults<T: clap::Args + clap::FromArgMatches>() -> T {
    let cmd = T::augment_args(clap::Command::new("defaults").no_binary_name(true));
    let parsed = cmd
        .try_get_matches_from(std::iter::empty::<String>())
        .and_then(|m| T::from_arg_matches(&m));
    match parsed {
        Ok(t) => t,
        // A group with a required flag has no defaults: a programming error, caught by the
        // unit tests of every group.
        Err(e) => panic!("an option group without defaults: {e}"),
    }
}

/// Which lidar map is the training target.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum TargetKind {
    /// ±K accumulated sweeps (SPEC §4 dense target; falls back to sparse when absent).
    #[default]
    Dense,
    /// The keyframe sweep only.
    Sparse,
}

impl depthsense_base::words::Words for TargetKind {
    const WHAT: &'static str = "target";
    const WORDS: &'static [(&'static str, Self)] =
        &[("dense", Self::Dense), ("sparse", Self::Sparse)];
}

/// The learning-rate schedule, the epochs and the batches (SPEC §8; the defaults are the
/// paper's).
#[derive(clap::Args, Debug, Clone, PartialEq, Serialize, Deserialize)]
#[command(next_help_heading = h::SCHEDULE)]
pub struct ScheduleOptions {
    /// Epochs (paper: 40).
    #[arg(long, default_value_t = 40, value_parser = ranges::count, allow_negative_numbers = true)]
    pub epochs: usize,
    /// Batch size (paper: 8).
    #[arg(long, default_value_t = 8, value_parser = ranges::count, allow_negative_numbers = true)]
    pub batch_size: usize,
    /// Initial learning rate (paper: 1e-3).
    #[arg(long, default_value_t = 1e-3, value_parser = ranges::positive, allow_negative_numbers = true)]
    pub lr: f64,
    /// Power of the per-iteration polynomial decay to 0 (paper: 0.9).
    #[arg(long, default_value_t = 0.9, value_parser = ranges::non_negative, allow_negative_numbers = true)]
    pub lr_power: f64,
    /// SGD momentum (paper: 0.9).
    #[arg(long, default_value_t = 0.9, value_parser = ranges::probability, allow_negative_numbers = true)]
    pub momentum: f64,
    /// Weight decay (paper: 1e-4).
    #[arg(long, default_value_t = 1e-4, value_parser = ranges::non_negative, allow_negative_numbers = true)]
    pub weight_decay: f64,
    /// Seed of initialisation, shuffling, augmentation and dropout.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Linear learning-rate warmup over the first N iterations, then the poly decay (0 = none,
    /// the paper).
    #[arg(long = "warmup", default_value_t = 0, value_name = "N", value_parser = ranges::non_negative_u64, allow_negative_numbers = true)]
    #[serde(default, skip_serializing_if = "is_default")]
    pub warmup_iters: u64,
    /// Make each epoch N iterations drawn from consecutive passes over the training samples
    /// (each pass a fresh shuffle), whatever their number: runs on 100 or 3,000 images then take
    /// --epochs × N iterations and validate every N. Default: an epoch is one pass.
    #[arg(long, value_name = "N", value_parser = ranges::count_u64, allow_negative_numbers = true)]
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub epoch_iterations: Option<u64>,
    /// Train on at most this many batches per epoch (quick runs).
    #[arg(long, value_parser = ranges::count, allow_negative_numbers = true)]
    pub max_batches_per_epoch: Option<usize>,
}

impl Default for ScheduleOptions {
    fn default() -> Self {
        defaults()
    }
}

impl ScheduleOptions {
    /// Iterations of one epoch over `train_samples` training samples: `--epoch-iterations`,
    /// or one pass in full batches (at least 1), at most `--max-batches-per-epoch`.
    pub fn iterations_per_epoch(&self, train_samples: usize) -> u64 {
        if let Some(n) = self.epoch_iterations {
            return n.max(1);
        }
        let natural = (train_samples / self.batch_size.max(1)).max(1);
        self.max_batches_per_epoch
            .map_or(natural, |m| m.min(natural).max(1)) as u64
    }
}

/// How the training samples are loaded and augmented.
#[derive(clap::Args, Debug, Clone, PartialEq, Serialize, Deserialize)]
#[command(next_help_heading = h::DATA)]
pub struct LoadingOptions {
    /// Data-loader threads (0 = all cores).
    #[arg(long, default_value_t = 0, value_parser = ranges::non_negative_usize, allow_negative_numbers = true)]
    pub jobs: usize,
    /// Batches decoded ahead of the training step.
    #[arg(long, default_value_t = 4, value_parser = ranges::count, allow_negative_numbers = true)]
    pub prefetch: usize,
    /// Training target: dense (±K accumulated lidar) or sparse (keyframe sweep).
    #[arg(long, default_value = "dense", value_parser = words::<TargetKind>())]
    pub target: TargetKind,
    /// Disable flip and brightness/colour/gamma jitter (SPEC §8 augmentation; on by default).
    #[arg(long = "no-augment", action = clap::ArgAction::SetFalse)]
    pub augment: bool,
    /// Training-time radar dropout (not in the paper): each training sample loses a fraction
    /// U(0, P) of its radar returns with their height-extended strips, so that the network
    /// cannot read "no return here" as a depth cue. 0 = off. docs/guide/train.md.
    #[arg(long, default_value_t = 0.0, value_name = "P", value_parser = ranges::probability, allow_negative_numbers = true)]
    #[serde(default, skip_serializing_if = "is_default")]
    pub train_radar_drop: f64,
    /// The oracle radar (an upper bound, not a model): every radar return keeps its pixel but
    /// takes the lidar target's depth there (or the nearest valid target pixel within 3 px;
    /// returns without one are dropped), strips redrawn as SPEC §5 draws them; in training and
    /// validation. Needs radar_points.bin (prepare writes it). docs/guide/experiments.md.
    #[arg(long)]
    #[serde(default, skip_serializing_if = "is_default")]
    pub radar_oracle: bool,
    /// Train on the first N training samples only, in a fixed order of the samples (nested for
    /// growing N, the same for every seed): training-set size experiments. Validation and test
    /// scenes are unchanged.
    #[arg(long, value_name = "N", value_parser = ranges::count, allow_negative_numbers = true)]
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_subset: Option<usize>,
}

impl Default for LoadingOptions {
    fn default() -> Self {
        defaults()
    }
}

/// The validation samples of a training run.
#[derive(clap::Args, Debug, Clone, PartialEq, Serialize, Deserialize)]
#[command(next_help_heading = h::VALIDATION)]
pub struct ValidationOptions {
    /// Only for data prepared without validation lists: every N-th training scene (sorted by
    /// name) is held out for validation (and, without any split lists, every N-th scene is
    /// test and the one before it validation). Never selects on test scenes.
    #[arg(long, default_value_t = 5, value_parser = ranges::count, allow_negative_numbers = true)]
    pub val_every_scene: usize,
    /// Validate on at most this many validation samples (evenly spaced).
    #[arg(long, value_parser = ranges::count, allow_negative_numbers = true)]
    pub max_val_samples: Option<usize>,
}

impl Default for ValidationOptions {
    fn default() -> Self {
        defaults()
    }
}

/// When a run writes its checkpoints, where it stops, and what it does with a run folder that
/// holds a run: `train`'s and `mer train`'s (the training engine, `depthsense_train::learner`,
/// applies them to both).
#[derive(clap::Args, Debug, Clone, PartialEq, Serialize, Deserialize)]
#[command(next_help_heading = h::OUTPUT)]
pub struct CheckpointOptions {
    /// Also write OUT/last.safetensors every N iterations (0 = only at epoch ends).
    #[arg(long, default_value_t = 0, value_parser = ranges::non_negative_u64, allow_negative_numbers = true)]
    pub checkpoint_every: u64,
    /// Stop after this global iteration (checkpointed; continue with --resume).
    #[arg(long, value_parser = ranges::count_u64, allow_negative_numbers = true)]
    pub stop_after: Option<u64>,
    /// Continue exactly from OUT/last.safetensors (same options required), inside an epoch
    /// where it stopped. A finished run is reported as finished (exit status 0); `train` trains
    /// it longer with --extend.
    #[arg(long)]
    pub resume: bool,
    /// Start over in an --out that holds a run: its config.json, metrics.jsonl, curves.png and
    /// checkpoints are removed first (other files stay). Without --resume or --force such a
    /// folder is refused.
    #[arg(long, conflicts_with = "resume")]
    #[serde(default, skip_serializing_if = "is_default")]
    pub force: bool,
}

impl Default for CheckpointOptions {
    fn default() -> Self {
        defaults()
    }
}

/// `train --extend`: a finished run trained longer (`train` only).
#[derive(clap::Args, Debug, Clone, PartialEq, Serialize, Deserialize)]
#[command(next_help_heading = h::OUTPUT)]
pub struct ExtendOptions {
    /// Train the run in OUT longer: continue from OUT/last.safetensors to --epochs (more than
    /// it had) with a new learning-rate schedule from there (poly decay from --lr to 0 at the
    /// new end; the same batch size and seed). config.json records every schedule segment.
    #[arg(long, conflicts_with = "force")]
    #[serde(default, skip_serializing_if = "is_default")]
    pub extend: bool,
}

impl Default for ExtendOptions {
    /// A switch is off unless given. (Not [`defaults`]: alone, without [`CheckpointOptions`],
    /// this group's conflict with `--force` names no flag.)
    fn default() -> Self {
        ExtendOptions { extend: false }
    }
}

/// Iterations between loss reads on CUDA by default ([`HardwareOptions::loss_read_every`] = 0).
pub const CUDA_LOSS_READ_EVERY: u64 = 25;

/// The device, its arithmetic and how often it is synchronised.
#[derive(clap::Args, Debug, Clone, PartialEq, Serialize, Deserialize)]
#[command(next_help_heading = h::DEVICE)]
pub struct HardwareOptions {
    #[command(flatten)]
    #[serde(flatten)]
    pub device: DeviceArg,
    /// Mixed precision (bf16 autocast of the forward pass; CUDA only, ignored on CPU).
    #[arg(long)]
    pub amp: bool,
    /// Read the training loss to the host every N iterations (one GPU synchronisation per N;
    /// always before checkpoints and at epoch ends). 0 = 1 on the CPU and in data-parallel
    /// jobs, 25 on CUDA.
    #[arg(long, default_value_t = 0, value_name = "N", value_parser = ranges::non_negative_u64, allow_negative_numbers = true)]
    #[serde(default, skip_serializing_if = "is_default")]
    pub loss_read_every: u64,
}

impl Default for HardwareOptions {
    fn default() -> Self {
        defaults()
    }
}

/// A data-parallel job's settings (not part of RUN/config.json's options: a run trains the
/// same with any of them, SyncBatchNorm aside).
#[derive(clap::Args, Debug, Clone, PartialEq, Serialize, Deserialize)]
#[command(next_help_heading = h::DISTRIBUTED)]
pub struct DistributedOptions {
    /// Data-parallel: start N local worker processes (one per GPU, or N CPU processes) with
    /// the environment torchrun sets. --batch-size is the global batch (a multiple of N).
    /// Under torchrun / srun leave this out: the workers read RANK, WORLD_SIZE, … themselves.
    #[arg(long, value_name = "N", value_parser = ranges::count, allow_negative_numbers = true)]
    pub nproc: Option<usize>,
    /// With --nproc: the rendezvous port on 127.0.0.1 (default: a free one).
    #[arg(long)]
    pub master_port: Option<u16>,
    /// Data-parallel: SyncBatchNorm (batch statistics over the global batch), so N ranks
    /// train as one process with the same global batch.
    #[arg(long)]
    pub sync_bn: bool,
    /// Data-parallel: seconds before a rendezvous or collective fails (naming the peer).
    #[arg(long, default_value_t = 300, value_parser = ranges::count_u64, allow_negative_numbers = true)]
    pub dist_timeout: u64,
    /// Data-parallel: gradient all-reduce bucket size in MB (DDP's default 25).
    #[arg(long, default_value_t = 25.0, value_parser = ranges::positive, allow_negative_numbers = true)]
    pub bucket_mb: f64,
    /// Data-parallel: after every step check that each rank's model equals rank 0's
    /// (bitwise; one broadcast of the model per step — for tests and debugging).
    #[arg(long)]
    pub check_replicas: bool,
}

impl Default for DistributedOptions {
    fn default() -> Self {
        defaults()
    }
}

impl DistributedOptions {
    /// The all-reduce bucket in bytes.
    pub fn bucket_bytes(&self) -> usize {
        (self.bucket_mb.max(0.001) * 1024.0 * 1024.0) as usize
    }

    /// The rendezvous and collective timeout (at least a second).
    pub fn timeout(&self) -> std::time::Duration {
        std::time::Duration::from_secs(self.dist_timeout.max(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    /// `train`'s groups as the command line flattens them.
    #[derive(Parser, Debug)]
    struct Flat {
        #[command(flatten)]
        schedule: ScheduleOptions,
        #[command(flatten)]
        loading: LoadingOptions,
        #[command(flatten)]
        validation: ValidationOptions,
        #[command(flatten)]
        checkpointing: CheckpointOptions,
        #[command(flatten)]
        extension: ExtendOptions,
        #[command(flatten)]
        hardware: HardwareOptions,
        #[command(flatten)]
        distributed: DistributedOptions,
        /// Stands for `train --init-from` (which conflicts with --resume and --extend).
        #[arg(long, conflicts_with_all = ["resume", "extend"])]
        init_from: Option<String>,
    }

    #[test]
    fn every_group_has_the_papers_defaults_written_once() {
        let s = ScheduleOptions::default();
        assert_eq!((s.epochs, s.batch_size, s.lr, s.seed), (40, 8, 1e-3, 0));
        assert_eq!((s.lr_power, s.momentum, s.weight_decay), (0.9, 0.9, 1e-4));
        assert_eq!((s.warmup_iters, s.epoch_iterations), (0, None));
        let l = LoadingOptions::default();
        assert!(l.augment && !l.radar_oracle && l.target == TargetKind::Dense);
        assert_eq!((l.jobs, l.prefetch, l.train_radar_drop), (0, 4, 0.0));
        assert_eq!(ValidationOptions::default().val_every_scene, 5);
        assert_eq!(CheckpointOptions::default().checkpoint_every, 0);
        assert_eq!(HardwareOptions::default().device.name, "auto");
        assert_eq!(DistributedOptions::default().dist_timeout, 300);
        // The defaults are what the command line gives when no flag is given.
        let f = Flat::try_parse_from(["x"]).unwrap();
        assert_eq!(f.schedule, s);
        assert_eq!(f.loading, l);
        assert_eq!(f.extension, ExtendOptions::default());
    }

    #[test]
    fn flags_keep_their_names_ranges_and_conflicts_across_groups() {
        let f = Flat::try_parse_from([
            "x",
            "--warmup",
            "7",
            "--no-augment",
            "--target",
            "sparse",
            "--device",
            "cpu",
            "--stop-after",
            "3",
        ])
        .unwrap();
        assert_eq!(f.schedule.warmup_iters, 7);
        assert!(!f.loading.augment);
        assert_eq!(f.loading.target, TargetKind::Sparse);
        assert_eq!(f.hardware.device.name, "cpu");
        assert_eq!(f.checkpointing.stop_after, Some(3));
        let e = Flat::try_parse_from(["x", "--lr=-1"])
            .unwrap_err()
            .to_string();
        assert!(e.contains("--lr") && e.contains("greater than 0"), "{e}");
        let e = Flat::try_parse_from(["x", "--epochs", "-3"])
            .unwrap_err()
            .to_string();
        assert!(e.contains("--epochs") && e.contains("at least 1"), "{e}");
        assert!(Flat::try_parse_from(["x", "--resume", "--force"]).is_err());
        assert!(Flat::try_parse_from(["x", "--extend", "--init-from", "w"]).is_err());
        assert!(Flat::try_parse_from(["x", "--extend", "--force"]).is_err());
        assert!(
            Flat::try_parse_from(["x", "--extend"])
                .unwrap()
                .extension
                .extend
        );
    }

    #[test]
    fn the_json_keeps_its_flat_keys_and_leaves_out_what_is_off() {
        #[derive(Serialize, Deserialize, PartialEq, Debug)]
        struct Record {
            #[serde(flatten)]
            schedule: ScheduleOptions,
            #[serde(flatten)]
            loading: LoadingOptions,
            #[serde(flatten)]
            hardware: HardwareOptions,
        }
        let r = Record {
            schedule: ScheduleOptions::default(),
            loading: LoadingOptions::default(),
            hardware: HardwareOptions::default(),
        };
        let v = serde_json::to_value(&r).unwrap();
        assert_eq!(v["epochs"], 40);
        assert_eq!(v["device"], "auto");
        assert_eq!(v["augment"], true);
        assert!(v.get("warmup_iters").is_none() && v.get("train_radar_drop").is_none());
        assert_eq!(serde_json::from_value::<Record>(v).unwrap(), r);
    }

    #[test]
    fn an_epoch_is_one_pass_in_full_batches_unless_told() {
        let mut s = ScheduleOptions {
            batch_size: 4,
            ..Default::default()
        };
        assert_eq!(s.iterations_per_epoch(10), 2);
        assert_eq!(s.iterations_per_epoch(3), 1);
        s.max_batches_per_epoch = Some(1);
        assert_eq!(s.iterations_per_epoch(10), 1);
        s.epoch_iterations = Some(35);
        assert_eq!(s.iterations_per_epoch(10), 35);
    }
}
