//! `depthsense demo`: synthetic world → prepare → train RGB-only and radar fusion → eval →
//! OUT/report/.

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Output directory (world/, prepared/, rgb/, fusion/, report/).
    #[arg(long, default_value = "runs/demo")]
    pub out: PathBuf,
    /// Device: auto (CUDA when available: more epochs and batch 8), cpu, cuda or cuda:N.
    #[arg(long, default_value = "auto", value_parser = depthsense_config::cli::parse_device)]
    pub device: String,
    /// A much smaller run (a few scenes, a few steps): checks the pipeline end to end.
    #[arg(long)]
    pub quick: bool,
    /// Seed of the world, initialisation and training (both models use the same).
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Override the number of training epochs of each model (on a CPU an epoch is 35
    /// iterations whatever the world's size: 10 by default).
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Override the number of scenes of the synthetic world (default 60, a lean world: ≈ 420
    /// training images).
    #[arg(long)]
    pub scenes: Option<usize>,
    /// Override the keyframes per scene of the synthetic world (default 10).
    #[arg(long)]
    pub keyframes_per_scene: Option<usize>,
    /// Worker threads of synth / prepare / loader (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub jobs: usize,
    /// Number of test samples drawn in the report.
    #[arg(long, default_value_t = 4)]
    pub pictures: usize,
    /// Replace a demo already in --out (its world, prepared data, runs and report); without
    /// it such a folder is refused.
    #[arg(long)]
    pub force: bool,
}
