//! `depthsense bench model`: forward and training-step time (and GPU memory) of a network.

use std::path::PathBuf;

use crate::cmd::heading as h;

#[derive(clap::Args)]
pub struct Args {
    #[arg(long, help_heading = h::MODEL, alias = "preset", default_value = "released", value_parser = depthsense_config::cli::parse_config_spec,
          help = depthsense_config::cli::config_help("Network", ", a model-config JSON file or a checkpoint (RUN/best.safetensors: its network with its trained weights, so that the bf16 check is on a trained network)"))]
    pub config: String,
    #[arg(long = "set", help_heading = h::MODEL, value_name = "KEY=VALUE", value_parser = depthsense_config::cli::parse_set,
          help = crate::cmd::SET_HELP)]
    pub set: Vec<String>,
    #[command(flatten, next_help_heading = h::DEVICE)]
    pub device: depthsense_config::device::DeviceArg,
    /// Batch size of the forward (inference) benchmark; 0 skips it.
    #[arg(long, help_heading = h::TIMING, default_value_t = 3)]
    pub batch_forward: i64,
    /// Batch size of the training-step benchmark: the step `train` runs (forward, the ordinal
    /// loss on a sparse target, backward, depthsense's SGD update); 0 skips it.
    #[arg(long, help_heading = h::TIMING, default_value_t = 8)]
    pub batch_train: i64,
    /// Input height.
    #[arg(long, help_heading = h::TIMING, default_value_t = 350)]
    pub height: i64,
    /// Input width.
    #[arg(long, help_heading = h::TIMING, default_value_t = 800)]
    pub width: i64,
    /// Untimed warm-up iterations (cuDNN autotuning, first allocations).
    #[arg(long, help_heading = h::TIMING, default_value_t = 3)]
    pub warmup_runs: usize,
    /// Timed iterations; the median is reported.
    #[arg(long, help_heading = h::TIMING, default_value_t = 10)]
    pub repeats: usize,
    /// Arithmetic: fp32, bf16 (CUDA autocast to bfloat16) or fp16 (CUDA autocast to float16).
    /// Ignored on the CPU.
    #[arg(long, help_heading = h::DEVICE, default_value = "fp32",
          value_parser = crate::cmd::words::words::<depthsense_config::flags::Precision>())]
    pub precision: depthsense_config::flags::Precision,
    /// Store conv weights and inputs channels-last (NHWC) so cuDNN can use NHWC kernels.
    #[arg(long, help_heading = h::DEVICE)]
    pub channels_last: bool,
    /// Time the forward phases on the inference graph that `predict` and `eval` run
    /// (BatchNorm folded into the convs, the fused ordinal decode on the CPU) instead of the
    /// training graph in evaluation mode; the training step is the same either way.
    #[arg(long, help_heading = h::MODEL)]
    pub inference_graph: bool,
    /// Also time forward + decode replayed from a CUDA graph captured for this batch shape (a
    /// build with the feature `cuda-graphs`, fp32, CUDA); otherwise that row runs eagerly and
    /// the JSON's `cuda_graph` says why.
    #[arg(long, help_heading = h::DEVICE)]
    pub cuda_graph: bool,
    /// cuDNN autotuning (`cudnn.benchmark`); on by default, `--cudnn-benchmark false` to disable.
    #[arg(long, help_heading = h::DEVICE, default_value_t = true, action = clap::ArgAction::Set)]
    pub cudnn_benchmark: bool,
    /// CPU threads for libtorch (default: libtorch's choice, all cores).
    #[arg(long, help_heading = h::DEVICE)]
    pub threads: Option<i32>,
    /// Write the results as JSON to this file.
    #[arg(long, help_heading = h::OUTPUT, value_name = "FILE")]
    pub out: Option<PathBuf>,
}
