//! The help headings of the commands with many flags (`help_heading`), one word for one group
//! everywhere: the option groups of [`crate::training`] and every command's own flags.

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
