//! `depthsense explain`: Grad-CAM++ maps by distance class (SPEC §10.6) of a checkpoint on
//! prepared samples, with and without radar (target and formulas: docs/guide/experiments.md, "Grad-CAM++ by distance class").

use std::path::PathBuf;

use crate::cmd::heading as h;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten, next_help_heading = h::MODEL)]
    pub model: crate::cmd::model_source::ModelSource,
    /// One prepared sample directory (repeatable).
    #[arg(long, help_heading = h::DATA, conflicts_with = "data")]
    pub sample: Vec<PathBuf>,
    /// Or: a prepared data directory; its --split samples, at most --max-samples of them.
    #[arg(long, help_heading = h::DATA)]
    pub data: Option<PathBuf>,
    /// With --data: held-out (test scenes), all, or a split name.
    #[arg(long, help_heading = h::DATA, default_value = "held-out")]
    pub split: String,
    /// With --data: how many samples (evenly spaced).
    #[arg(long, help_heading = h::DATA, default_value_t = 2)]
    pub max_samples: usize,
    /// Distance classes d in metres, comma separated.
    #[arg(long, help_heading = h::EXPERIMENT, value_delimiter = ',', default_value = "35,55,70")]
    pub distances: Vec<f64>,
    /// Half-width of the band around d, as a fraction of d (0.1 = ±10 %).
    #[arg(long, help_heading = h::EXPERIMENT, default_value_t = 0.1)]
    pub band: f64,
    /// Layers, comma separated: rgb.layer1 … rgb.layer4, decoder, radar (late fusion).
    #[arg(long, help_heading = h::EXPERIMENT, value_delimiter = ',', default_value = "rgb.layer4,radar")]
    pub layer: Vec<String>,
    /// Output directory: overlays, grid.png, explain.{json,md}.
    #[arg(long, help_heading = h::OUTPUT)]
    pub out: PathBuf,
    #[command(flatten, next_help_heading = h::DEVICE)]
    pub device: depthsense_config::device::DeviceArg,
    /// Replace the results of an earlier `explain` in --out (its explain.json, explain.md,
    /// grid.png and overlays of the same names); without it they are refused.
    #[arg(long, help_heading = h::OUTPUT)]
    pub force: bool,
}
