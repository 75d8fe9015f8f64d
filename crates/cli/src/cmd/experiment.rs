//! `depthsense experiment …`: SPEC §10 experiments built from training runs.
//! `ablation`: fusion variants (SPEC §6) and loss (SPEC §10.4) × seeds, tested on test scenes.

use std::path::PathBuf;
use std::process::ExitCode;

use depthsense_metrics::{Aggregate, EvalConfig, Protocol};
use depthsense_train::experiments::ablation::{
    run_ablation, AblationOptions, Variant, MD_FILE, PNG_FILE,
};
use indicatif::MultiProgress;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Experiment,
}

#[derive(clap::Subcommand)]
enum Experiment {
    /// Train every variant (rgb, early, late, late-sam, l1, l2) with each seed on the same data,
    /// evaluate each run's best checkpoint (chosen on the validation scenes) on the TEST scenes
    /// and write OUT/ablation.{md,csv,json,png}: mean ± std over seeds. Resumable: finished
    /// runs are skipped, unfinished ones continue from their last checkpoint.
    Ablation(AblationArgs),
}

#[derive(clap::Args)]
pub struct AblationArgs {
    /// Prepared data directory (output of `depthsense prepare`, holds index.json); it must
    /// have test scenes.
    #[arg(long)]
    data: PathBuf,
    /// Output directory: runs/<variant>/seed<k>/ and ablation.{md,csv,json,png}.
    #[arg(long)]
    out: PathBuf,
    /// Model preset the variants start from: paper, released, tiny, tiny-wide, or a
    /// model-config JSON file.
    #[arg(long, default_value = "paper")]
    preset: String,
    /// Number of seeds: 0, 1, …, N−1.
    #[arg(long, default_value_t = 3, conflicts_with = "seed_list")]
    seeds: u64,
    /// Explicit seeds instead of --seeds, comma separated (e.g. 0,7,11).
    #[arg(long, value_delimiter = ',')]
    seed_list: Option<Vec<u64>>,
    /// Variants, comma separated: rgb (no radar), early (early fusion), late (late fusion, no
    /// attention), late-sam (late fusion + spatial attention: the paper's model), l1 / l2
    /// (late-sam with an L1 / L2 depth head instead of the ordinal one).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "rgb,early,late,late-sam,l1,l2"
    )]
    variants: Vec<String>,
    /// Any model-config field as key=value (repeatable), applied to the preset before the
    /// variant's fusion / attention / head; e.g. `--set width=8 --set dropout=0`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Epochs of each run (paper: 40).
    #[arg(long, default_value_t = 40)]
    epochs: usize,
    /// Batch size of training and evaluation (paper: 8).
    #[arg(long, default_value_t = 8)]
    batch_size: usize,
    /// Initial learning rate (paper: 1e-3).
    #[arg(long, default_value_t = 1e-3)]
    lr: f64,
    /// Device: auto (CUDA when available), cpu, cuda or cuda:N.
    #[arg(long, default_value = "auto")]
    device: String,
    /// Data-loader threads (0 = all cores). Runs are trained one after another.
    #[arg(long, default_value_t = 0)]
    jobs: usize,
    /// Validate (checkpoint selection) on at most this many validation samples.
    #[arg(long)]
    max_val_samples: Option<usize>,
    /// Train on at most this many batches per epoch (quick runs).
    #[arg(long)]
    max_batches_per_epoch: Option<usize>,
    /// Only for data without split lists: the trainer's scene partition period (see
    /// `depthsense train --help`).
    #[arg(long, default_value_t = 5)]
    val_every_scene: usize,
    /// Test protocol beyond the cap: mask (drop) or clamp (peers').
    #[arg(long, default_value = "mask")]
    protocol: String,
    /// Test aggregation: image (per image, then mean) or pooled (over all pixels).
    #[arg(long, default_value = "image")]
    aggregate: String,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    match a.command {
        Experiment::Ablation(a) => ablation(a),
    }
}

fn ablation(a: AblationArgs) -> anyhow::Result<ExitCode> {
    let variants = a
        .variants
        .iter()
        .filter(|s| !s.trim().is_empty())
        .map(|s| s.parse::<Variant>())
        .collect::<Result<Vec<_>, _>>()?;
    let seeds = match a.seed_list {
        Some(l) => l,
        None => (0..a.seeds).collect(),
    };
    let opts = AblationOptions {
        data: a.data,
        out: a.out,
        preset: a.preset,
        set: a.set,
        variants,
        seeds,
        epochs: a.epochs,
        batch_size: a.batch_size,
        lr: a.lr,
        device: a.device,
        jobs: a.jobs,
        max_val_samples: a.max_val_samples,
        max_batches_per_epoch: a.max_batches_per_epoch,
        val_every_scene: a.val_every_scene,
        eval: EvalConfig {
            protocol: a.protocol.parse::<Protocol>()?,
            aggregate: a.aggregate.parse::<Aggregate>()?,
            ..EvalConfig::default()
        },
        command_line: Some(std::env::args().collect::<Vec<_>>().join(" ")),
    };
    let mp = MultiProgress::new();
    let r = run_ablation(&opts, &mp)?;
    println!(
        "{:<10} {:>3}  {:>17}  {:>17}  {:>17}",
        "variant", "n", "test RMSE (m)", "δ1", "AbsRel"
    );
    for (name, _) in &r.models {
        let row = r.row(name, "combined", "full");
        let f =
            |s: Option<depthsense_train::experiments::Stat>| s.map_or("–".into(), |s| s.fmt(3));
        println!(
            "{:<10} {:>3}  {:>17}  {:>17}  {:>17}",
            name,
            row.map_or(0, |x| x.n),
            f(row.and_then(|x| x.rmse)),
            f(row.and_then(|x| x.delta1)),
            f(row.and_then(|x| x.abs_rel)),
        );
    }
    for v in r.verdicts.iter().filter(|v| v.metric == "rmse") {
        println!("{}", v.text);
    }
    eprintln!(
        "{} runs: {} trained, {} resumed, {} evaluated only, skipped {} (finished before); \
         {:.1} s; test scenes: {}",
        r.runs.len(),
        r.trained,
        r.resumed,
        r.evaluated,
        r.skipped,
        r.total_seconds,
        r.partition.test_scenes.join(", ")
    );
    eprintln!(
        "report: {} (chart {})",
        opts.out.join(MD_FILE).display(),
        opts.out.join(PNG_FILE).display()
    );
    Ok(ExitCode::SUCCESS)
}
