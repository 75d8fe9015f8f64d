//! Every subcommand's flags (`Args`, torch-free, parsed by both binaries) and the `run` of
//! the commands that need no network. The network commands' `run` live in
//! `src/bin/depthsense-net/<name>.rs`.

/// The help of every `--set`: what it does and the one place that lists every key
/// (`depthsense model-info --keys`, and the last section of docs/guide/cli.md, both generated
/// from `depthsense_config::options`) — the list itself is printed nowhere else.
pub const SET_HELP: &str = "Override one model-config option, KEY=VALUE, repeatable, applied in \
     order; every key and its values: `depthsense model-info --keys`";

/// The help headings of the commands with many flags (`help_heading`), one word for one group
/// everywhere.
pub mod heading {
    /// What is read: prepared data, a dataroot, the samples and how they are loaded.
    pub const DATA: &str = "Data";
    /// The network: its configuration, weights and overrides.
    pub const MODEL: &str = "Model";
    /// The learning-rate schedule, the epochs and the batches of training.
    pub const SCHEDULE: &str = "Schedule";
    /// Validation during training.
    pub const VALIDATION: &str = "Validation";
    /// How depth is scored.
    pub const SCORING: &str = "Scoring";
    /// How the radar is gathered.
    pub const RADAR: &str = "Radar";
    /// Sensor failure at test time.
    pub const FAILURE: &str = "Sensor failure";
    /// How a network runs over prepared samples (`inference_args`).
    pub const INFERENCE: &str = "Inference";
    /// What is written and where; an output folder's existing content.
    pub const OUTPUT: &str = "Output";
    /// The device, arithmetic and threads.
    pub const DEVICE: &str = "Device";
    /// Data-parallel training.
    pub const DISTRIBUTED: &str = "Data-parallel";
    /// The inputs of one prediction.
    pub const INPUT: &str = "Input";
    /// The world generated.
    pub const WORLD: &str = "World";
    /// What a benchmark times.
    pub const TIMING: &str = "Timing";
    /// The experiment's grid: variants, seeds, scenarios.
    pub const EXPERIMENT: &str = "Experiment";
}

pub mod bench;
pub mod bench_data;
pub mod bench_export;
pub mod bench_model;
pub mod bench_synth;
pub mod bench_train;
pub mod calibration;
pub mod demo;
pub mod device_arg;
pub mod eval;
pub mod experiment;
pub mod explain;
pub mod export;
pub mod help_markdown;
pub mod index;
pub mod inference_args;
pub mod inspect;
pub mod mer;
pub mod model_info;
pub mod model_source;
pub mod predict;
pub mod prepare;
pub mod progress;
pub mod radar_args;
pub mod ranges;
pub mod report;
pub mod scoring_args;
pub mod synth;
pub mod train;
pub mod words;
