//! How a network runs over prepared samples: `--batch-size`, `--device`, `--jobs` and
//! `--max-samples`, one flag group for `eval` and `experiment failure|perturb` (flattened into
//! their arguments), with the same defaults and help.

#[derive(clap::Args, Debug, Clone)]
pub struct InferenceArgs {
    /// Batch size of inference.
    #[arg(long, default_value_t = 4, value_parser = crate::cmd::ranges::count, allow_negative_numbers = true)]
    pub batch_size: usize,
    #[command(flatten)]
    pub device: depthsense_config::device::DeviceArg,
    /// Data-loader threads (0 = all cores).
    #[arg(long, default_value_t = 0, value_parser = crate::cmd::ranges::non_negative_usize, allow_negative_numbers = true)]
    pub jobs: usize,
    /// Evaluate at most this many samples (evenly spaced).
    #[arg(long, value_parser = crate::cmd::ranges::count, allow_negative_numbers = true)]
    pub max_samples: Option<usize>,
    /// Replay each batch's forward and decode from a CUDA graph captured for its shape (a
    /// build with the feature `cuda-graphs`, fp32, CUDA): one launch instead of hundreds. Any
    /// other batch runs eagerly, and the log says why once.
    #[arg(long)]
    pub cuda_graph: bool,
}
