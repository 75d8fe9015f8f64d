//! `depthsense predict`: depth for a prepared sample, a sample token of a dataroot, or raw
//! files (JPEG + radar PCDs + calibration JSON).

use std::path::PathBuf;

use crate::cmd::heading as h;

/// `predict --help`'s examples (each parsed by the docs test through docs/guide/cli.md).
const EXAMPLES: &str = "Examples:
  depthsense predict --checkpoint runs/paper/best.safetensors --sample data/prepared/ca9a282c9e77460f8360f564131a8af5
  depthsense predict --checkpoint runs/paper/best.safetensors --data data/prepared --split held-out --out preds/paper
  depthsense predict --checkpoint runs/paper/best.safetensors --dataroot data/nuscenes --token ca9a282c9e77460f8360f564131a8af5
  depthsense predict --checkpoint runs/paper/best.safetensors --dataroot data/nuscenes --tokens tokens.txt --out preds/frames
  depthsense predict --checkpoint runs/paper/best.safetensors --image cam.jpg --calibration cam.json
(docs/guide/deploy.md: the four inputs, a list of tokens, raw files and their calibration)";

#[derive(clap::Args)]
#[command(after_help = EXAMPLES)]
pub struct Args {
    #[command(flatten, next_help_heading = h::MODEL)]
    pub model: super::model_source::ModelSource,
    /// Input 1: a prepared sample directory (holds image.png, radar_*.png, meta.json).
    #[arg(long, help_heading = h::INPUT, conflicts_with_all = ["token", "tokens", "image", "data"])]
    pub sample: Option<PathBuf>,
    /// Input 4: every sample of a split of a prepared data directory; writes
    /// OUT/<token>.png (16-bit, depth×256) and/or OUT/<token>.npy (float32 metres), the
    /// layout `eval --predictions` reads.
    #[arg(long, help_heading = h::INPUT, conflicts_with_all = ["token", "tokens", "image"])]
    pub data: Option<PathBuf>,
    /// With --data: held-out (test scenes), all, or a split name of the index.
    #[arg(long, help_heading = h::INPUT, default_value = "held-out", requires = "data")]
    pub split: String,
    /// With --data: file formats, comma separated (png, npy).
    #[arg(long, help_heading = h::OUTPUT, value_delimiter = ',', default_value = "png", requires = "data",
          value_parser = crate::cmd::words::words::<depthsense_score::predictions::PredFormat>())]
    pub format: Vec<depthsense_score::predictions::PredFormat>,
    /// With --data: batch size of inference.
    #[arg(long, help_heading = h::INPUT, default_value_t = 4, requires = "data", value_parser = crate::cmd::ranges::count, allow_negative_numbers = true)]
    pub batch_size: usize,
    /// With --data: replay each batch's forward and decode from a CUDA graph captured for its
    /// shape (a build with the feature `cuda-graphs`, fp32, CUDA); any other batch runs eagerly
    /// and the log says why once.
    #[arg(long, help_heading = h::INPUT, requires = "data")]
    pub cuda_graph: bool,
    /// Input 2: a sample token of --dataroot (its maps are computed like `prepare` does).
    /// Repeatable (or comma-separated): more than one token is a list, predicted in a pipeline
    /// — loader threads build the frames from the raw files while the network runs — each into
    /// OUT/<token>/, with images/s and the per-frame latency at the end.
    #[arg(long, help_heading = h::INPUT, requires = "dataroot", conflicts_with = "image", value_delimiter = ',')]
    pub token: Vec<String>,
    /// Input 2 as a list from a file: sample tokens of --dataroot, one a line (blank lines and
    /// `#` comments skipped); predicted as a list of --token.
    #[arg(long, help_heading = h::INPUT, requires = "dataroot", conflicts_with = "image", value_name = "FILE")]
    pub tokens: Option<PathBuf>,
    /// Loader threads of a token list (0 = all cores): they build frames while the network
    /// runs.
    #[arg(long, help_heading = h::INPUT, default_value_t = 0, value_parser = crate::cmd::ranges::non_negative_usize, allow_negative_numbers = true)]
    pub jobs: usize,
    /// nuScenes-format dataroot for --token.
    #[arg(long, help_heading = h::INPUT)]
    pub dataroot: Option<PathBuf>,
    /// Version folder for --token.
    #[arg(long, help_heading = h::INPUT, default_value = "v1.0-mini")]
    pub version: String,
    /// Input 3: a 1600x900 CAM_FRONT JPEG (with --calibration; without it the command says
    /// how to write one).
    #[arg(long, help_heading = h::INPUT)]
    pub image: Option<PathBuf>,
    /// Radar .pcd files for --image (repeat the flag or separate with commas); each must be
    /// in the calibration. Default: every file the calibration lists.
    #[arg(long, help_heading = h::INPUT, value_delimiter = ',')]
    pub radar: Vec<PathBuf>,
    /// Calibration JSON for --image: the camera intrinsics and, per radar file, its channel,
    /// sweep, time and sweep → camera transform — `depthsense calibration` writes one from a
    /// nuScenes sample (docs/guide/deploy.md, "Raw files"). Without --image, one or more
    /// (repeated, comma-separated, or several after one flag: `--calibration frames/*.json`)
    /// are a list of raw frames: each names its camera JPEG (`camera_file`) and radar files,
    /// predicted in a pipeline into OUT/<calibration file name>/.
    #[arg(long, help_heading = h::INPUT, num_args = 1.., value_delimiter = ',', conflicts_with_all = ["token", "tokens", "data", "sample"])]
    pub calibration: Vec<PathBuf>,
    /// Keep every radar point (disable the devkit filters) for --image / --token.
    #[arg(long, help_heading = h::INPUT)]
    pub no_radar_filters: bool,
    /// Output directory: depth.png (16-bit, depth×256), depth_color.png, radar_overlay.png,
    /// image.png.
    #[arg(long, help_heading = h::OUTPUT, default_value = "predict")]
    pub out: PathBuf,
    /// Depth of the far end of the colour map, metres.
    #[arg(long, help_heading = h::OUTPUT, default_value_t = 80.0)]
    pub max_depth: f32,
    #[command(flatten, next_help_heading = h::DEVICE)]
    pub device: depthsense_config::device::DeviceArg,
    /// PDA checkpoint (`depthsense mer train`) that computes the MER maps of the input, for
    /// a model trained with `--radar-input mer` (SPEC §5). Needed for --token and --image;
    /// a prepared sample uses the maps `mer apply` wrote unless this is given.
    #[arg(long, help_heading = h::MODEL)]
    pub mer_checkpoint: Option<PathBuf>,
    /// Replace predictions an earlier `predict` wrote in --out (only the files this run
    /// writes); without it they are refused before anything is computed.
    #[arg(long, help_heading = h::OUTPUT)]
    pub force: bool,
}
