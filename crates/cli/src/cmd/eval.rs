//! `depthsense eval`: the paper's tables (SPEC §10 items 1–3) for a checkpoint.

use std::path::PathBuf;
use std::process::ExitCode;

use depthsense_metrics::{Aggregate, EvalConfig, Protocol};
use depthsense_train::evaluate::{load_model, run_eval_loaded, write_tables, EvalOptions};

#[derive(clap::Args)]
pub struct Args {
    /// Checkpoint written by `train` (e.g. RUN/best.safetensors), or a PyTorch state dict
    /// such as the authors' paper_weights_rvmde.pth together with `--config released`.
    #[arg(long)]
    checkpoint: PathBuf,
    /// Architecture: a preset (paper, released, tiny) or a model-config JSON. Required for a
    /// PyTorch .pth; for a depthsense checkpoint it replaces the stored config.
    #[arg(long)]
    config: Option<String>,
    /// Override one config option, `key=value`, repeatable (keys as in `model-info --set`).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Prepared data directory (holds index.json).
    #[arg(long)]
    data: PathBuf,
    /// Output directory for tables.md, tables.csv and tables.json
    /// (default: an `eval/` folder beside the checkpoint).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Samples: held-out (the `test` split, or the scenes `train` held out), all, or a split
    /// name of the index (test-day, test-night, official-val, …).
    #[arg(long, default_value = "held-out")]
    split: String,
    /// Scene modulo `train` used to hold scenes out when no split lists matched.
    #[arg(long, default_value_t = 5)]
    val_every_scene: usize,
    /// Fraction of radar points removed at random (1.0 = radar absent): sensor failure.
    #[arg(long, default_value_t = 0.0)]
    radar_drop: f64,
    /// Seed of the radar drop.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Pixels beyond the cap: mask (dropped, default) or clamp (GT and prediction clamped).
    #[arg(long, default_value = "mask")]
    protocol: String,
    /// Aggregation: image (metrics per image, then mean; default) or pooled (over pixels).
    #[arg(long, default_value = "image")]
    aggregate: String,
    /// Depth caps in metres (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "50,70,80")]
    caps: Vec<f64>,
    /// Batch size of inference.
    #[arg(long, default_value_t = 4)]
    batch_size: usize,
    /// Device: auto, cpu, cuda or cuda:N.
    #[arg(long, default_value = "auto")]
    device: String,
    /// Data-loader threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    jobs: usize,
    /// Evaluate at most this many samples (evenly spaced).
    #[arg(long)]
    max_samples: Option<usize>,
    /// Radar map(s): height, raw or raw-height (default: from the checkpoint's config).
    #[arg(long)]
    radar_input: Option<String>,
    /// Model name in the tables.
    #[arg(long, default_value = "model")]
    name: String,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let out = a.out.clone().unwrap_or_else(|| {
        a.checkpoint
            .parent()
            .map(|p| p.join("eval"))
            .unwrap_or_else(|| PathBuf::from("eval"))
    });
    let opts = EvalOptions {
        checkpoint: a.checkpoint,
        config: a.config,
        set: a.set,
        data: a.data,
        split: a.split,
        val_every_scene: a.val_every_scene,
        eval: EvalConfig {
            caps_m: a.caps,
            protocol: a.protocol.parse::<Protocol>()?,
            aggregate: a.aggregate.parse::<Aggregate>()?,
            ..EvalConfig::default()
        },
        radar_drop: a.radar_drop,
        seed: a.seed,
        batch_size: a.batch_size,
        device: a.device,
        jobs: a.jobs,
        max_samples: a.max_samples,
        radar_input: a.radar_input.as_deref().map(str::parse).transpose()?,
        name: a.name.clone(),
    };
    let device = depthsense_model::device::parse_device(&opts.device)?;
    let (loaded, load_report) =
        load_model(&opts.checkpoint, opts.config.as_deref(), &opts.set, device)?;
    if let Some(r) = &load_report {
        eprint!("{}: {r}", opts.checkpoint.display());
    }
    let pb = super::train::progress_bar("eval");
    let report = run_eval_loaded(&opts, &loaded, &pb)?;
    pb.finish_and_clear();
    let models = [(a.name.as_str(), &report)];
    write_tables(&out, &models)?;
    println!("{}", depthsense_metrics::tables::markdown_report(&models));
    eprintln!(
        "{} images evaluated (radar drop {}); tables written to {}/tables.{{md,csv,json}}",
        report.images_seen,
        opts.radar_drop,
        out.display()
    );
    Ok(ExitCode::SUCCESS)
}
