//! How depth is scored beyond the cap and averaged: `--protocol` and `--aggregate`, one flag
//! group for `eval`, `train` (its validation) and `experiment ablation` (its tests), so that the
//! three accept the same words with the same help (SPEC §9; docs/guide/evaluate.md).

use depthsense_metrics::{Aggregate, Protocol};

use super::words::words;

#[derive(clap::Args, Debug, Clone)]
pub struct ScoringArgs {
    /// Pixels beyond the cap: mask (dropped, default), clamp (GT and prediction clamped:
    /// peers'), or radarnet (RadarNet's evaluation: 0 < GT < cap, prediction not clipped,
    /// per image then mean; docs/guide/evaluate.md, "RadarNet's protocol").
    #[arg(long, default_value = "mask", value_parser = words::<Protocol>())]
    pub protocol: Protocol,
    /// Aggregation: image (metrics per image, then mean; default) or pooled (over pixels).
    #[arg(long, default_value = "image", value_parser = words::<Aggregate>())]
    pub aggregate: Aggregate,
}
