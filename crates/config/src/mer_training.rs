//! The option groups of `mer train` (MER's association network, SPEC §5) that are its own —
//! each defined once, its defaults in its flags' attributes, as [`crate::training`]'s are. The
//! validation samples and the checkpointing are `train`'s groups
//! ([`crate::training::ValidationOptions`], [`crate::training::CheckpointOptions`]).
//!
//! | group | heading | what |
//! |---|---|---|
//! | [`MerScheduleOptions`] | Schedule | epochs, batches, Adam's learning rate and its decay, seed |
//! | [`MerLoadingOptions`] | Data | loader threads, flips |

use serde::{Deserialize, Serialize};

use crate::heading as h;
use crate::ranges;
use crate::training::defaults;

/// `mer train`'s schedule: Adam with a per-iteration polynomial decay to 0.
#[derive(clap::Args, Debug, Clone, PartialEq, Serialize, Deserialize)]
#[command(next_help_heading = h::SCHEDULE)]
pub struct MerScheduleOptions {
    /// Epochs.
    #[arg(long, default_value_t = 20, value_parser = ranges::count, allow_negative_numbers = true)]
    pub epochs: usize,
    /// Images per batch (each brings all of its labelled radar pixels).
    #[arg(long, default_value_t = 4, value_parser = ranges::count, allow_negative_numbers = true)]
    pub batch_size: usize,
    /// Adam's initial learning rate (1e-2: validation AUC 0.584 after 4 epochs on the
    /// 20-scene synthetic world; 1e-3: 0.501 after 1; docs/guide/mer.md).
    #[arg(long, default_value_t = 1e-2, value_parser = ranges::positive, allow_negative_numbers = true)]
    pub lr: f64,
    /// Power of the per-iteration polynomial decay of the learning rate to 0.
    #[arg(long, default_value_t = 0.9, value_parser = ranges::non_negative, allow_negative_numbers = true)]
    pub lr_power: f64,
    /// Weight decay (Adam's L2 term).
    #[arg(long, default_value_t = 1e-4, value_parser = ranges::non_negative, allow_negative_numbers = true)]
    pub weight_decay: f64,
    /// Seed of initialisation, shuffling and flips.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

impl Default for MerScheduleOptions {
    fn default() -> Self {
        defaults()
    }
}

impl MerScheduleOptions {
    /// Iterations of one epoch over `train_samples` labelled samples: one pass in full batches
    /// (at least 1).
    pub fn iterations_per_epoch(&self, train_samples: usize) -> u64 {
        (train_samples / self.batch_size.max(1)).max(1) as u64
    }
}

/// How `mer train` loads and augments its samples.
#[derive(clap::Args, Debug, Clone, PartialEq, Serialize, Deserialize)]
#[command(next_help_heading = h::DATA)]
pub struct MerLoadingOptions {
    /// Data-loader threads (0 = all cores).
    #[arg(long, default_value_t = 0, value_parser = ranges::non_negative_usize, allow_negative_numbers = true)]
    pub jobs: usize,
    /// Disable the horizontal flip (p = 0.5; the association window is left/right symmetric).
    #[arg(long = "no-augment", action = clap::ArgAction::SetFalse)]
    pub augment: bool,
}

impl Default for MerLoadingOptions {
    fn default() -> Self {
        defaults()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::training::{CheckpointOptions, ValidationOptions};
    use clap::Parser;

    /// `mer train`'s groups as the command line flattens them.
    #[derive(Parser, Debug)]
    struct Flat {
        #[command(flatten)]
        schedule: MerScheduleOptions,
        #[command(flatten)]
        loading: MerLoadingOptions,
        #[command(flatten)]
        validation: ValidationOptions,
        #[command(flatten)]
        checkpointing: CheckpointOptions,
    }

    #[test]
    fn the_defaults_are_the_flags_and_flatten_without_clashes() {
        let s = MerScheduleOptions::default();
        assert_eq!((s.epochs, s.batch_size, s.lr, s.seed), (20, 4, 1e-2, 0));
        assert_eq!((s.lr_power, s.weight_decay), (0.9, 1e-4));
        let l = MerLoadingOptions::default();
        assert_eq!((l.jobs, l.augment), (0, true));
        let f = Flat::try_parse_from(["x"]).unwrap();
        assert_eq!(f.schedule, s);
        assert_eq!(f.loading, l);
        let f = Flat::try_parse_from(["x", "--no-augment", "--epochs", "3", "--resume"]).unwrap();
        assert!(!f.loading.augment && f.checkpointing.resume);
        assert_eq!(f.schedule.epochs, 3);
        assert!(Flat::try_parse_from(["x", "--resume", "--force"]).is_err());
        assert!(Flat::try_parse_from(["x", "--epochs", "0"]).is_err());
    }

    #[test]
    fn an_epoch_is_one_pass_in_full_batches() {
        let s = MerScheduleOptions::default();
        assert_eq!(s.iterations_per_epoch(10), 2);
        assert_eq!(s.iterations_per_epoch(3), 1);
    }
}
