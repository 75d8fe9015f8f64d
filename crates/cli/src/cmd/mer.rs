//! `depthsense mer train | apply | report`: MER, the multi-channel enhanced radar (SPEC §5).

use std::path::PathBuf;
use std::process::ExitCode;

use depthsense_mer::apply::{apply, MerApplyOptions};
use depthsense_mer::report::{mer_report, report_markdown};
use depthsense_mer::train::{train_pda, MerTrainOptions};
use depthsense_model::pda::PdaConfig;
use depthsense_nuscenes::fsutil::write_atomic;

use super::train::progress_bar;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Subcommand)]
enum Command {
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
struct TrainArgs {
    /// Prepared data directory (holds index.json).
    #[arg(long)]
    data: PathBuf,
    /// Run directory: config.json, metrics.jsonl, curves.png, last/best.safetensors.
    #[arg(long, default_value = "runs/mer")]
    out: PathBuf,
    /// PDA preset: paper (32/64/128/256 channels), tiny (8/16/32/64), fast (tiny on the grid
    /// folded 2x2: ≈ 3x cheaper), test, or a JSON file.
    #[arg(long, default_value = "paper")]
    config: String,
    /// Channels of the appearance-affinity term added to the head (0 = RC-PDA's plain head;
    /// default: the preset's). See README, MER.
    #[arg(long)]
    affinity: Option<i64>,
    /// Epochs.
    #[arg(long, default_value_t = 20)]
    epochs: usize,
    /// Batch size.
    #[arg(long, default_value_t = 4)]
    batch_size: usize,
    /// Initial learning rate (Adam, poly decay 0.9 per iteration).
    #[arg(long, default_value_t = 1e-2)]
    lr: f64,
    /// Weight decay.
    #[arg(long, default_value_t = 1e-4)]
    weight_decay: f64,
    /// Seed of initialisation, shuffling and flips.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Device: auto, cpu, cuda or cuda:N.
    #[arg(long, default_value = "auto")]
    device: String,
    /// Continue from OUT/last.safetensors (same options required).
    #[arg(long)]
    resume: bool,
    /// Start over in an --out that holds a PDA run (its run files are removed first); without
    /// --resume or --force such a folder is refused.
    #[arg(long, conflicts_with = "resume")]
    force: bool,
    /// Loader threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    jobs: usize,
    /// Disable the horizontal flip augmentation.
    #[arg(long)]
    no_augment: bool,
    /// Validate on at most this many validation samples (evenly spaced).
    #[arg(long)]
    max_val_samples: Option<usize>,
    /// Only without validation lists: every N-th training scene is held out for validation.
    #[arg(long, default_value_t = 5)]
    val_every_scene: usize,
}

#[derive(clap::Args)]
struct ApplyArgs {
    /// PDA checkpoint written by `mer train` (e.g. RUN/best.safetensors).
    #[arg(long)]
    checkpoint: PathBuf,
    /// Prepared data directory; the maps are written into its sample folders.
    #[arg(long)]
    data: PathBuf,
    /// Device: auto, cpu, cuda or cuda:N.
    #[arg(long, default_value = "auto")]
    device: String,
    /// Threads reading and encoding maps (0 = all cores).
    #[arg(long, default_value_t = 0)]
    jobs: usize,
    /// Samples per forward pass.
    #[arg(long, default_value_t = 4)]
    batch_size: usize,
    /// libtorch threads of the network on a CPU (0 = all cores, or all but one for a PDA on
    /// the folded grid such as `fast`, whose reading and writing then need a core).
    #[arg(long, default_value_t = 0)]
    network_threads: usize,
    /// Recompute every sample; needed to replace maps written by another PDA model.
    #[arg(long)]
    force: bool,
    /// Write preview pictures (raw, height-extended, MER at θ = 0.5 and 0.9) for N samples
    /// (evenly spaced over the test samples, or over all when the index has none).
    #[arg(long, default_value_t = 0)]
    preview: usize,
    /// Folder of the preview pictures (default DATA/mer_preview).
    #[arg(long)]
    preview_dir: Option<PathBuf>,
}

#[derive(clap::Args)]
struct ReportArgs {
    /// Prepared data directory with MER maps (`mer apply`).
    #[arg(long)]
    data: PathBuf,
    /// Split: held-out (the test scenes of the train/val/test partition), or any split tag.
    #[arg(long, default_value = "held-out")]
    split: String,
    /// Ignore GT beyond this depth, metres.
    #[arg(long, default_value_t = 80.0)]
    cap: f64,
    /// Also write the report as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    match a.command {
        Command::Train(t) => run_train(t),
        Command::Apply(x) => run_apply(x),
        Command::Report(r) => run_report(r),
    }
}

fn run_train(a: TrainArgs) -> anyhow::Result<ExitCode> {
    let opts = MerTrainOptions {
        data: a.data,
        out: a.out,
        pda: {
            let mut c = PdaConfig::resolve(&a.config)?;
            if let Some(e) = a.affinity {
                c.affinity_channels = e;
                c.validate()?;
            }
            c
        },
        epochs: a.epochs,
        batch_size: a.batch_size,
        lr: a.lr,
        weight_decay: a.weight_decay,
        seed: a.seed,
        device: a.device,
        resume: a.resume,
        force: a.force,
        jobs: a.jobs,
        augment: !a.no_augment,
        max_val_samples: a.max_val_samples,
        val_every_scene: a.val_every_scene,
        ..MerTrainOptions::default()
    };
    let pb = progress_bar("mer");
    let s = train_pda(&opts, &pb)?;
    pb.finish_and_clear();
    for v in &s.val {
        eprintln!(
            "epoch {:>3}: val loss {:.4} precision {:.3} recall {:.3} AUC {:.3} ({} pairs, {} positive)",
            v.epoch, v.loss, v.precision, v.recall, v.auc, v.pairs, v.positives
        );
    }
    eprintln!(
        "PDA {} ({} parameters): best val AUC {:.3}, {} iterations in {:.1} s → {}",
        opts.pda.name,
        s.parameters,
        s.best_auc,
        s.iterations,
        s.seconds,
        s.run_dir.display()
    );
    Ok(ExitCode::SUCCESS)
}

fn run_apply(a: ApplyArgs) -> anyhow::Result<ExitCode> {
    let opts = MerApplyOptions {
        data: a.data,
        checkpoint: a.checkpoint,
        device: a.device,
        jobs: a.jobs,
        batch_size: a.batch_size,
        network_threads: a.network_threads,
        force: a.force,
        preview: a.preview,
        preview_dir: a.preview_dir,
    };
    let pb = progress_bar("mer");
    let s = apply(&opts, &pb)?;
    pb.finish_and_clear();
    eprintln!(
        "MER maps: {} written ({:.2} samples/s; network {:.1} ms/image), {} already done, \
         {:.1} s → {}",
        s.written,
        s.samples_per_s,
        1e3 * s.network_seconds / s.written.max(1) as f64,
        s.skipped,
        s.seconds,
        opts.data.display()
    );
    for p in &s.previews {
        println!("{}", p.display());
    }
    Ok(ExitCode::SUCCESS)
}

fn run_report(a: ReportArgs) -> anyhow::Result<ExitCode> {
    let mut r = mer_report(&a.data, &a.split, a.cap)?;
    r.command_line = Some(std::env::args().collect::<Vec<_>>().join(" "));
    print!("{}", report_markdown(&r));
    if let Some(p) = &a.json {
        write_atomic(p, serde_json::to_string_pretty(&r)?.as_bytes())?;
    }
    Ok(ExitCode::SUCCESS)
}
