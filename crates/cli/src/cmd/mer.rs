//! `depthsense mer train | apply | report`: MER, the multi-channel enhanced radar (SPEC §5).

use std::path::PathBuf;
use std::process::ExitCode;

use depthsense_base::fsutil::write_atomic;
use depthsense_score::mer_coverage::{mer_report, report_markdown};

use crate::cmd::heading as h;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(clap::Subcommand)]
pub enum Command {
    /// Train the PDA radar–pixel association network on prepared data (labels from the
    /// accumulated lidar: prepare with --lidar-sweeps K > 0).
    Train(TrainArgs),
    /// Write radar_mer_depth.png / radar_mer_conf.png into every prepared sample.
    Apply(ApplyArgs),
    /// Coverage and median relative error of raw, height-extended and MER radar against the
    /// sparse lidar GT.
    Report(ReportArgs),
}

#[derive(clap::Args)]
pub struct TrainArgs {
    /// Prepared data directory (holds index.json).
    #[arg(long, help_heading = h::DATA)]
    pub data: PathBuf,
    /// Run directory: config.json, metrics.jsonl, curves.png, last/best.safetensors.
    #[arg(long, help_heading = h::OUTPUT, default_value = "runs/mer")]
    pub out: PathBuf,
    /// PDA preset: paper (32/64/128/256 channels), tiny (8/16/32/64), fast (tiny on the grid
    /// folded 2x2: ≈ 3x cheaper), test, or a JSON file.
    #[arg(long, help_heading = h::MODEL, default_value = "paper")]
    pub config: String,
    /// Channels of the appearance-affinity term added to the head (0 = RC-PDA's plain head;
    /// default: the preset's). See docs/guide/mer.md.
    #[arg(long, help_heading = h::MODEL)]
    pub affinity: Option<i64>,
    #[command(flatten)]
    pub schedule: depthsense_config::mer_training::MerScheduleOptions,
    #[command(flatten)]
    pub loading: depthsense_config::mer_training::MerLoadingOptions,
    #[command(flatten)]
    pub validation: depthsense_config::training::ValidationOptions,
    #[command(flatten)]
    pub checkpointing: depthsense_config::training::CheckpointOptions,
    #[command(flatten, next_help_heading = h::DEVICE)]
    pub device: depthsense_config::device::DeviceArg,
}

#[derive(clap::Args)]
pub struct ApplyArgs {
    /// PDA checkpoint written by `mer train` (e.g. RUN/best.safetensors).
    #[arg(long, help_heading = h::MODEL)]
    pub checkpoint: PathBuf,
    /// Prepared data directory; the maps are written into its sample folders.
    #[arg(long, help_heading = h::DATA)]
    pub data: PathBuf,
    #[command(flatten, next_help_heading = h::DEVICE)]
    pub device: depthsense_config::device::DeviceArg,
    /// Threads reading and encoding maps (0 = all cores).
    #[arg(long, help_heading = h::DEVICE, default_value_t = 0)]
    pub jobs: usize,
    /// Samples per forward pass.
    #[arg(long, help_heading = h::DEVICE, default_value_t = 4)]
    pub batch_size: usize,
    /// libtorch threads of the network on a CPU (0 = all cores, or all but one for a PDA on
    /// the folded grid such as `fast`, whose reading and writing then need a core).
    #[arg(long, help_heading = h::DEVICE, default_value_t = 0)]
    pub network_threads: usize,
    /// Recompute every sample; needed to replace maps written by another PDA model.
    #[arg(long, help_heading = h::OUTPUT)]
    pub force: bool,
    /// Write preview pictures (raw, height-extended, MER at θ = 0.5 and 0.9) for N samples
    /// (evenly spaced over the test samples, or over all when the index has none).
    #[arg(long, help_heading = h::OUTPUT, default_value_t = 0)]
    pub preview: usize,
    /// Folder of the preview pictures (default DATA/mer_preview).
    #[arg(long, help_heading = h::OUTPUT)]
    pub preview_dir: Option<PathBuf>,
}

#[derive(clap::Args)]
pub struct ReportArgs {
    /// Prepared data directory with MER maps (`mer apply`).
    #[arg(long)]
    pub data: PathBuf,
    /// Split: held-out (the test scenes of the train/val/test partition), or any split tag.
    #[arg(long, default_value = "held-out")]
    pub split: String,
    /// Ignore GT beyond this depth, metres.
    #[arg(long, default_value_t = 80.0)]
    pub cap: f64,
    /// Also write the report as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// `mer report` (torch-free: `depthsense` runs it itself).
pub fn run_report(a: ReportArgs) -> anyhow::Result<ExitCode> {
    let mut r = mer_report(&a.data, &a.split, a.cap)?;
    r.command_line = Some(crate::command_line());
    print!("{}", report_markdown(&r));
    if let Some(p) = &a.json {
        write_atomic(p, serde_json::to_string_pretty(&r)?.as_bytes())?;
    }
    Ok(ExitCode::SUCCESS)
}
