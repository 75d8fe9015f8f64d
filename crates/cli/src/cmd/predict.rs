//! `depthsense predict`: depth for a prepared sample, a sample token of a dataroot, or raw
//! files (JPEG + radar PCDs + calibration JSON).

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub model: super::model_source::ModelSource,
    /// Input 1: a prepared sample directory (holds image.png, radar_*.png, meta.json).
    #[arg(long, conflicts_with_all = ["token", "image", "data"])]
    pub sample: Option<PathBuf>,
    /// Input 4: every sample of a split of a prepared data directory; writes
    /// OUT/<token>.png (16-bit, depth×256) and/or OUT/<token>.npy (float32 metres), the
    /// layout `eval --predictions` reads.
    #[arg(long, conflicts_with_all = ["token", "image"])]
    pub data: Option<PathBuf>,
    /// With --data: held-out (test scenes), all, or a split name of the index.
    #[arg(long, default_value = "held-out", requires = "data")]
    pub split: String,
    /// With --data: file formats, comma separated (png, npy).
    #[arg(long, value_delimiter = ',', default_value = "png", requires = "data",
          value_parser = crate::cmd::words::words::<depthsense_score::predictions::PredFormat>())]
    pub format: Vec<depthsense_score::predictions::PredFormat>,
    /// With --data: batch size of inference.
    #[arg(long, default_value_t = 4, requires = "data", value_parser = crate::cmd::ranges::count, allow_negative_numbers = true)]
    pub batch_size: usize,
    /// Input 2: a sample token of --dataroot (its maps are computed like `prepare` does).
    #[arg(long, requires = "dataroot", conflicts_with = "image")]
    pub token: Option<String>,
    /// nuScenes-format dataroot for --token.
    #[arg(long)]
    pub dataroot: Option<PathBuf>,
    /// Version folder for --token.
    #[arg(long, default_value = "v1.0-mini")]
    pub version: String,
    /// Input 3: a 1600x900 CAM_FRONT JPEG (with --calibration; without it the command says
    /// how to write one).
    #[arg(long)]
    pub image: Option<PathBuf>,
    /// Radar .pcd files for --image (repeat the flag or separate with commas); each must be
    /// in the calibration. Default: every file the calibration lists.
    #[arg(long, value_delimiter = ',')]
    pub radar: Vec<PathBuf>,
    /// Calibration JSON for --image: the camera intrinsics and, per radar file, its channel,
    /// sweep, time and sweep → camera transform — `depthsense calibration` writes one from a
    /// nuScenes sample (docs/guide/deploy.md, "Raw files").
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Keep every radar point (disable the devkit filters) for --image / --token.
    #[arg(long)]
    pub no_radar_filters: bool,
    /// Output directory: depth.png (16-bit, depth×256), depth_color.png, radar_overlay.png,
    /// image.png.
    #[arg(long, default_value = "predict")]
    pub out: PathBuf,
    /// Depth of the far end of the colour map, metres.
    #[arg(long, default_value_t = 80.0)]
    pub max_depth: f32,
    #[command(flatten)]
    pub device: crate::cmd::device_arg::DeviceArg,
    /// PDA checkpoint (`depthsense mer train`) that computes the MER maps of the input, for
    /// a model trained with `--radar-input mer` (SPEC §5). Needed for --token and --image;
    /// a prepared sample uses the maps `mer apply` wrote unless this is given.
    #[arg(long)]
    pub mer_checkpoint: Option<PathBuf>,
    /// Replace predictions an earlier `predict` wrote in --out (only the files this run
    /// writes); without it they are refused before anything is computed.
    #[arg(long)]
    pub force: bool,
}
