//! How the radar of a sample is gathered (SPEC §2, §5): the flags `prepare` and `calibration`
//! share, so that a calibration written for `predict --image` gathers the radar a model was
//! trained on with the same words.

use depthsense_prep::PrepareOptions;

#[derive(clap::Args, Debug, Clone)]
pub struct RadarArgs {
    /// Radar sweeps per channel: the keyframe sweep and N−1 previous ones.
    #[arg(long, default_value_t = 5)]
    pub radar_sweeps: usize,
    /// Radar channels to accumulate (comma-separated).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "RADAR_FRONT,RADAR_FRONT_LEFT,RADAR_FRONT_RIGHT"
    )]
    pub radar_channels: Vec<String>,
    /// Keep every radar point (disable the devkit filters invalid_state == 0,
    /// dyn_prop 0..=6, ambig_state == 3).
    #[arg(long)]
    pub no_radar_filters: bool,
    /// Move radar points of older sweeps by (vx_comp, vy_comp) × Δt to the camera time.
    #[arg(long)]
    pub radar_velocity_compensation: bool,
}

impl RadarArgs {
    /// Sets the radar fields of `opts`.
    pub fn apply(&self, opts: &mut PrepareOptions) {
        opts.radar_sweeps = self.radar_sweeps;
        opts.radar_channels = self.radar_channels.clone();
        opts.radar_filters = !self.no_radar_filters;
        opts.radar_velocity_compensation = self.radar_velocity_compensation;
    }
}
