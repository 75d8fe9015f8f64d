//! `depthsense experiment …`: SPEC §10 experiments built from training runs.
//! `ablation`: fusion variants (SPEC §6) and loss (SPEC §10.4) × seeds, tested on test scenes;
//! `reduced-data` (SPEC §10.5), `perturb` (SPEC §10.7), `failure` (SPEC §10.8), `cost`
//! (SPEC §10.9).

use depthsense_config::ranges;
use depthsense_config::training::{LoadingOptions, ScheduleOptions, ValidationOptions};
use std::path::PathBuf;

use crate::cmd::heading as h;

/// The default grid of `experiment reduced-data`: everything, then without half the day scenes, without night, without
/// rain (our reading of SPEC §10.5; the paper's exact fractions are not in the SPEC).
pub const DEFAULT_GRID: &str = "full;day=0.5;night=1;rain=1";

/// The default training-set sizes of `experiment data-scale` (≈ 100, 300, 1,000 and ≥ 3,000
/// distinct training images).
pub const DEFAULT_SIZES: &str = "100,300,1000,3000";

/// The default scenarios of `experiment failure`.
pub const DEFAULT_SCENARIOS: &str =
    "none;radar-drop=0.5;radar-drop=1;drop-radars=all;beyond=50;beyond=30;beyond=15;clutter=10;clutter=50";

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: Experiment,
}

#[derive(clap::Subcommand)]
pub enum Experiment {
    /// Train every variant (rgb, early, late, late-sam, l1, l2) with each seed on the same data,
    /// evaluate each run's best checkpoint (chosen on the validation scenes) on the TEST scenes
    /// and write OUT/ablation.{md,csv,json,png}: mean ± std over seeds. Resumable: finished
    /// runs are skipped, unfinished ones continue from their last checkpoint.
    Ablation(AblationArgs),
    /// Reduced training data (SPEC §10.5): train the model with a fraction of some
    /// condition's training scenes withheld (a grid of such exclusions × seeds), test every
    /// run on the same test scenes, table the test metrics per test condition:
    /// OUT/reduced_data.{md,csv,json,png}. Resumable like `ablation`.
    ReducedData(ReducedDataArgs),
    /// Radar's margin against training-set size at matched compute: each arm (rgb, late-sam,
    /// …) trains on N distinct training samples for each size — nested subsets, the same for
    /// every seed — with the same number of iterations at every N, selected on the same
    /// validation scenes, tested on the same test scenes; the margin over the first arm is
    /// paired over seeds per N: OUT/data_scale.{md,csv,json,png}. Resumable like `ablation`.
    DataScale(DataScaleArgs),
    /// Sensor failure (SPEC §10.8): one checkpoint evaluated under failure scenarios (random
    /// point drop, whole radars absent, returns beyond a range absent, clutter added):
    /// OUT/failure.{md,csv,json,png}.
    Failure(FailureArgs),
    /// Calibration perturbation (SPEC §10.7): one checkpoint evaluated with the radar→camera
    /// extrinsic rotated (yaw, pitch, roll about the radar's own position, camera axes) or
    /// translated (camera x, y, z) by each magnitude, a random sign per sample; radar maps
    /// are re-rasterised from each sample's radar_points.bin (written by `prepare`):
    /// OUT/perturb.{md,csv,json,png}.
    Perturb(PerturbArgs),
    /// Parameters, MACs and inference time (SPEC §10.9) of every preset × variant on this
    /// device, next to the paper's figures: OUT/cost.{md,csv,json}.
    Cost(CostArgs),
}

#[derive(clap::Args)]
pub struct CostArgs {
    /// Output directory for cost.{md,csv,json}.
    #[arg(long, help_heading = h::OUTPUT)]
    pub out: PathBuf,
    /// Replace results an earlier run of this experiment wrote in --out (only its own
    /// .md/.csv/.json/.png files); without it they are refused before anything is computed.
    #[arg(long, help_heading = h::OUTPUT)]
    pub force: bool,
    #[arg(long, help_heading = h::MODEL, alias = "presets", value_delimiter = ',', default_value = "paper,released,tiny", value_parser = depthsense_config::cli::parse_config_spec,
          help = depthsense_config::cli::config_help("Networks, comma separated", " or model-config JSON files"))]
    pub configs: Vec<String>,
    /// Fusion variants, comma separated (rgb, early, late, late-sam, l1, l2).
    #[arg(long, help_heading = h::EXPERIMENT, value_delimiter = ',', default_value = "rgb,early,late,late-sam",
          value_parser = crate::cmd::words::words::<depthsense_config::variant::Variant>())]
    pub variants: Vec<depthsense_config::variant::Variant>,
    /// Images per batch (paper: 3).
    #[arg(long, help_heading = h::TIMING, default_value_t = 3)]
    pub batch: i64,
    /// Input height (SPEC §3: 350).
    #[arg(long, help_heading = h::TIMING, default_value_t = 350)]
    pub height: i64,
    /// Input width (SPEC §3: 800).
    #[arg(long, help_heading = h::TIMING, default_value_t = 800)]
    pub width: i64,
    /// Untimed passes before the timed ones.
    #[arg(long, help_heading = h::TIMING, default_value_t = 1)]
    pub warmup_runs: usize,
    /// Timed passes.
    #[arg(long, help_heading = h::TIMING, default_value_t = 3)]
    pub repeats: usize,
    #[command(flatten, next_help_heading = h::DEVICE)]
    pub device: depthsense_config::device::DeviceArg,
}

/// The paper's schedule: the defaults of `train`'s flags ([`ScheduleOptions`]), which the
/// experiments' flags share.
fn schedule() -> ScheduleOptions {
    ScheduleOptions::default()
}

/// The training settings every run of `ablation` and `reduced-data` shares; their defaults are
/// `train`'s ([`depthsense_config::training`]).
#[derive(clap::Args)]
pub struct RunArgs {
    /// Prepared data directory (output of `depthsense prepare`, holds index.json); it must
    /// have test scenes.
    #[arg(long, help_heading = h::DATA)]
    pub data: PathBuf,
    #[arg(long, help_heading = h::MODEL, alias = "preset", default_value = "paper", value_parser = depthsense_config::cli::parse_config_spec,
          help = depthsense_config::cli::config_help("Network", " or a model-config JSON file"))]
    pub config: String,
    #[arg(long = "set", help_heading = h::MODEL, value_name = "KEY=VALUE", value_parser = depthsense_config::cli::parse_set,
          help = crate::cmd::SET_HELP)]
    pub set: Vec<String>,
    /// Epochs of each run (paper: 40).
    #[arg(long, help_heading = h::SCHEDULE, default_value_t = schedule().epochs, value_parser = ranges::count, allow_negative_numbers = true)]
    pub epochs: usize,
    /// Batch size of training and evaluation (paper: 8).
    #[arg(long, help_heading = h::SCHEDULE, default_value_t = schedule().batch_size, value_parser = ranges::count, allow_negative_numbers = true)]
    pub batch_size: usize,
    /// Initial learning rate (paper: 1e-3).
    #[arg(long, help_heading = h::SCHEDULE, default_value_t = schedule().lr, value_parser = ranges::positive, allow_negative_numbers = true)]
    pub lr: f64,
    #[command(flatten, next_help_heading = h::DEVICE)]
    pub device: depthsense_config::device::DeviceArg,
    /// Data-loader threads (0 = all cores). Runs are trained one after another.
    #[arg(long, help_heading = h::DEVICE, default_value_t = LoadingOptions::default().jobs, value_parser = ranges::non_negative_usize, allow_negative_numbers = true)]
    pub jobs: usize,
    /// Validate (checkpoint selection) on at most this many validation samples.
    #[arg(long, help_heading = h::VALIDATION, value_parser = ranges::count, allow_negative_numbers = true)]
    pub max_val_samples: Option<usize>,
    /// Train on at most this many batches per epoch (quick runs).
    #[arg(long, help_heading = h::SCHEDULE, value_parser = ranges::count, allow_negative_numbers = true)]
    pub max_batches_per_epoch: Option<usize>,
    /// Only for data without split lists: the trainer's scene partition period (see
    /// `depthsense train --help`).
    #[arg(long, help_heading = h::VALIDATION, default_value_t = ValidationOptions::default().val_every_scene, value_parser = ranges::count, allow_negative_numbers = true)]
    pub val_every_scene: usize,
    /// Training-time radar dropout: each training sample loses a fraction U(0, P) of its radar
    /// returns (0 = off, the paper). See `depthsense train --help`.
    #[arg(long, help_heading = h::DATA, default_value_t = LoadingOptions::default().train_radar_drop, value_parser = ranges::probability, allow_negative_numbers = true)]
    pub train_radar_drop: f64,
    /// Linear learning-rate warmup over the first N iterations (0 = none, the paper).
    #[arg(long, help_heading = h::SCHEDULE, default_value_t = schedule().warmup_iters, value_name = "N", value_parser = ranges::non_negative_u64, allow_negative_numbers = true)]
    pub warmup: u64,
    /// An epoch (one validation) is N iterations whatever the training-set size, cycling
    /// through the training set (the demo: 35); default: one pass. `data-scale` sets it itself.
    #[arg(long, help_heading = h::SCHEDULE, value_name = "N", value_parser = ranges::count_u64, allow_negative_numbers = true)]
    pub epoch_iterations: Option<u64>,
}

#[derive(clap::Args)]
pub struct ReducedDataArgs {
    #[command(flatten, next_help_heading = h::SCHEDULE)]
    pub run: RunArgs,
    /// Output directory: runs/<cell>/seed<k>/ and reduced_data.{md,csv,json,png}.
    #[arg(long, help_heading = h::OUTPUT)]
    pub out: PathBuf,
    /// Grid cells separated by `;`, each `full` or CONDITION=FRACTION[,…] (the training
    /// scenes withheld, see `train --exclude`).
    #[arg(long, help_heading = h::EXPERIMENT, default_value = DEFAULT_GRID)]
    pub grid: String,
    /// Number of seeds: 0, 1, …, N−1.
    #[arg(long, help_heading = h::EXPERIMENT, default_value_t = 1)]
    pub seeds: u64,
}

#[derive(clap::Args)]
pub struct DataScaleArgs {
    #[command(flatten, next_help_heading = h::SCHEDULE)]
    pub run: RunArgs,
    /// Output directory: runs/n<N>/<arm>/seed<k>/ and data_scale.{md,csv,json,png}.
    #[arg(long, help_heading = h::OUTPUT)]
    pub out: PathBuf,
    /// Training-set sizes N (distinct training samples), comma separated; the largest must
    /// not exceed the training samples of --data.
    #[arg(long, help_heading = h::EXPERIMENT, value_delimiter = ',', default_value = DEFAULT_SIZES)]
    pub sizes: Vec<usize>,
    /// Arms trained at every size, comma separated: an ablation variant (rgb, early, late,
    /// late-sam, l1, l2, late-sam-mer), optionally with model options joined by `+`
    /// (`late-sam+radar-skip=8`) and the word `oracle` for the oracle radar
    /// (`late-sam+oracle`, see train --radar-oracle). The first is the baseline of the margins.
    #[arg(long, help_heading = h::EXPERIMENT, value_delimiter = ',', default_value = "rgb,late-sam")]
    pub arms: Vec<String>,
    /// Arms trained at the largest size only (same form as --arms), e.g.
    /// `late-sam+radar-skip=8,late-sam+oracle,late-sam-mer`.
    #[arg(long, help_heading = h::EXPERIMENT, value_delimiter = ',')]
    pub at_largest: Vec<String>,
    /// Number of seeds: 0, 1, …, N−1.
    #[arg(long, help_heading = h::EXPERIMENT, default_value_t = 5, conflicts_with = "seed_list")]
    pub seeds: u64,
    /// Explicit seeds instead of --seeds, comma separated (e.g. 3,4: a second process's share
    /// of the runs; the tables of all seeds come from one more call with every seed, which
    /// reads the finished runs back).
    #[arg(long, help_heading = h::EXPERIMENT, value_delimiter = ',')]
    pub seed_list: Option<Vec<u64>>,
    /// Training iterations of every run (the same at every size), rounded up to a multiple
    /// of --epochs (the validations). Default: the fewest that show the largest size each
    /// image once, ⌈N_max / batch⌉; fewer are refused.
    #[arg(long, help_heading = h::SCHEDULE)]
    pub iterations: Option<u64>,
}

#[derive(clap::Args)]
pub struct FailureArgs {
    #[command(flatten, next_help_heading = h::MODEL)]
    pub model: crate::cmd::model_source::ModelSource,
    /// Prepared data directory.
    #[arg(long, help_heading = h::DATA)]
    pub data: PathBuf,
    /// Output directory for failure.{md,csv,json,png}.
    #[arg(long, help_heading = h::OUTPUT)]
    pub out: PathBuf,
    /// Replace results an earlier run of this experiment wrote in --out (only its own
    /// .md/.csv/.json/.png files); without it they are refused before anything is computed.
    #[arg(long, help_heading = h::OUTPUT)]
    pub force: bool,
    /// Scenarios separated by `;`; each `none` or settings joined by `,`: radar-drop=F
    /// (fraction of points), drop-radars=A+B (channel names or all), beyond=M (metres),
    /// clutter=N (ghost points per sample).
    #[arg(long, help_heading = h::EXPERIMENT, default_value = DEFAULT_SCENARIOS)]
    pub scenarios: String,
    /// Samples: held-out (test scenes), all, or a split name.
    #[arg(long, help_heading = h::DATA, default_value = "held-out")]
    pub split: String,
    /// Seed of the random drop and the clutter.
    #[arg(long, help_heading = h::EXPERIMENT, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten, next_help_heading = h::INFERENCE)]
    pub run: crate::cmd::inference_args::InferenceArgs,
}

#[derive(clap::Args)]
pub struct PerturbArgs {
    #[command(flatten, next_help_heading = h::MODEL)]
    pub model: crate::cmd::model_source::ModelSource,
    /// Prepared data directory (prepared with radar_points.bin: a current `prepare`).
    #[arg(long, help_heading = h::DATA)]
    pub data: PathBuf,
    /// Output directory for perturb.{md,csv,json,png}.
    #[arg(long, help_heading = h::OUTPUT)]
    pub out: PathBuf,
    /// Replace results an earlier run of this experiment wrote in --out (only its own
    /// .md/.csv/.json/.png files); without it they are refused before anything is computed.
    #[arg(long, help_heading = h::OUTPUT)]
    pub force: bool,
    /// Rotation magnitudes in degrees (yaw, pitch, roll), comma separated.
    #[arg(long, help_heading = h::EXPERIMENT, value_delimiter = ',', default_value = "0.5,1,2,5")]
    pub rotate_deg: Vec<f64>,
    /// Translation magnitudes in metres (x, y, z), comma separated.
    #[arg(long, help_heading = h::EXPERIMENT, value_delimiter = ',', default_value = "0.1,0.25,0.5")]
    pub translate_m: Vec<f64>,
    /// Axes, comma separated: yaw (camera vertical), pitch (camera x), roll (optical axis),
    /// x (right), y (down), z (forward).
    #[arg(long, help_heading = h::EXPERIMENT, value_delimiter = ',', default_value = "yaw,pitch,roll,x,y,z",
          value_parser = crate::cmd::words::words::<depthsense_prep::radar_points::PerturbAxis>())]
    pub axes: Vec<depthsense_prep::radar_points::PerturbAxis>,
    /// Samples: held-out (test scenes), all, or a split name.
    #[arg(long, help_heading = h::DATA, default_value = "held-out")]
    pub split: String,
    /// Seed of the per-sample sign (+ or − the magnitude).
    #[arg(long, help_heading = h::EXPERIMENT, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten, next_help_heading = h::INFERENCE)]
    pub run: crate::cmd::inference_args::InferenceArgs,
}

#[derive(clap::Args)]
pub struct AblationArgs {
    #[command(flatten, next_help_heading = h::SCHEDULE)]
    pub run: RunArgs,
    /// Output directory: runs/<variant>/seed<k>/ and ablation.{md,csv,json,png}.
    #[arg(long, help_heading = h::OUTPUT)]
    pub out: PathBuf,
    /// Number of seeds: 0, 1, …, N−1. Each seed trains every variant; the verdicts are a
    /// paired test over the seeds (docs/guide/experiments.md, "The ablation, with seeds").
    #[arg(long, help_heading = h::EXPERIMENT, default_value_t = 5, conflicts_with = "seed_list")]
    pub seeds: u64,
    /// Explicit seeds instead of --seeds, comma separated (e.g. 0,7,11).
    #[arg(long, help_heading = h::EXPERIMENT, value_delimiter = ',')]
    pub seed_list: Option<Vec<u64>>,
    /// Variants, comma separated: rgb (no radar), early (early fusion), late (late fusion, no
    /// attention), late-sam (late fusion + spatial attention: the paper's model), l1 / l2
    /// (late-sam with an L1 / L2 depth head instead of the ordinal one), late-sam-mer
    /// (late-sam on raw + 6 MER channels; run `depthsense mer apply` on the data first).
    #[arg(
        long,
        help_heading = h::EXPERIMENT,
        value_delimiter = ',',
        default_value = "rgb,early,late,late-sam,l1,l2",
        value_parser = crate::cmd::words::words::<depthsense_config::variant::Variant>()
    )]
    pub variants: Vec<depthsense_config::variant::Variant>,
    /// The tests' scoring (the same flags as `eval`).
    #[command(flatten, next_help_heading = h::SCORING)]
    pub scoring: crate::cmd::scoring_args::ScoringArgs,
}
