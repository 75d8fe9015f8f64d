//! `depthsense experiment …`: SPEC §10 experiments built from training runs.
//! `ablation`: fusion variants (SPEC §6) and loss (SPEC §10.4) × seeds, tested on test scenes;
//! `reduced-data` (SPEC §10.5), `perturb` (SPEC §10.7), `failure` (SPEC §10.8), `cost`
//! (SPEC §10.9).

use std::path::PathBuf;
use std::process::ExitCode;

use depthsense_experiments::ablation::{
    run_ablation, AblationOptions, AblationResult, Variant, MD_FILE, PNG_FILE,
};
use depthsense_experiments::runner::RunSettings;
use depthsense_metrics::{Aggregate, EvalConfig, Protocol};
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
    /// Reduced training data (SPEC §10.5): train the model with a fraction of some
    /// condition's training scenes withheld (a grid of such exclusions × seeds), test every
    /// run on the same test scenes, table the test metrics per test condition:
    /// OUT/reduced_data.{md,csv,json,png}. Resumable like `ablation`.
    ReducedData(ReducedDataArgs),
    /// Sensor failure (SPEC §10.8): one checkpoint evaluated under failure scenarios (random
    /// point drop, whole radars absent, returns beyond a range absent, clutter added):
    /// OUT/failure.{md,csv,json,png}.
    Failure(FailureArgs),
    /// Calibration perturbation (SPEC §10.7): one checkpoint evaluated with the radar→camera
    /// extrinsic rotated (yaw, pitch, roll about the radar's own position, camera axes) or
    /// translated (camera x, y, z) by each magnitude, a random sign per sample; radar maps
    /// are re-rasterised from each sample's radar_points.bin (written by `prepare`):
    /// OUT/perturb.{md,csv,json,png}.
    Perturb(PerturbArgs),
    /// Parameters, MACs and inference time (SPEC §10.9) of every preset × variant on this
    /// device, next to the paper's figures: OUT/cost.{md,csv,json}.
    Cost(CostArgs),
}

#[derive(clap::Args)]
pub struct CostArgs {
    /// Output directory for cost.{md,csv,json}.
    #[arg(long)]
    out: PathBuf,
    /// Replace results an earlier run of this experiment wrote in --out (only its own
    /// .md/.csv/.json/.png files); without it they are refused before anything is computed.
    #[arg(long)]
    force: bool,
    /// Presets (paper, released, tiny, tiny-wide) or model-config JSON files, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "paper,released,tiny")]
    presets: Vec<String>,
    /// Fusion variants, comma separated (rgb, early, late, late-sam, l1, l2).
    #[arg(long, value_delimiter = ',', default_value = "rgb,early,late,late-sam")]
    variants: Vec<String>,
    /// Images per batch (paper: 3).
    #[arg(long, default_value_t = 3)]
    batch: i64,
    /// Input height (SPEC §3: 350).
    #[arg(long, default_value_t = 350)]
    height: i64,
    /// Input width (SPEC §3: 800).
    #[arg(long, default_value_t = 800)]
    width: i64,
    /// Untimed passes before timing.
    #[arg(long, default_value_t = 1)]
    warmup: usize,
    /// Timed passes.
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// Device: auto, cpu, cuda or cuda:N.
    #[arg(long, default_value = "auto")]
    device: String,
}

/// The training settings every run of `ablation` and `reduced-data` shares.
#[derive(clap::Args)]
pub struct RunArgs {
    /// Prepared data directory (output of `depthsense prepare`, holds index.json); it must
    /// have test scenes.
    #[arg(long)]
    data: PathBuf,
    /// Model preset: paper, released, tiny, tiny-wide, or a model-config JSON file.
    #[arg(long, default_value = "paper")]
    preset: String,
    /// Any model-config field as key=value (repeatable), applied to the preset (in `ablation`
    /// not fusion, attention or head: the variants set those); e.g. `--set width=8 --set
    /// dropout=0`.
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
    /// Training-time radar dropout: each training sample loses a fraction U(0, P) of its radar
    /// returns (0 = off, the paper). See `depthsense train --help`.
    #[arg(long, default_value_t = 0.0)]
    train_radar_drop: f64,
    /// Linear learning-rate warmup over the first N iterations (0 = none, the paper).
    #[arg(long, default_value_t = 0, value_name = "N")]
    warmup: u64,
}

impl RunArgs {
    fn settings(self) -> RunSettings {
        RunSettings {
            data: self.data,
            preset: self.preset,
            set: self.set,
            epochs: self.epochs,
            batch_size: self.batch_size,
            lr: self.lr,
            device: self.device,
            jobs: self.jobs,
            max_val_samples: self.max_val_samples,
            max_batches_per_epoch: self.max_batches_per_epoch,
            val_every_scene: self.val_every_scene,
            train_radar_drop: self.train_radar_drop,
            warmup_iters: self.warmup,
        }
    }
}

#[derive(clap::Args)]
pub struct ReducedDataArgs {
    #[command(flatten)]
    run: RunArgs,
    /// Output directory: runs/<cell>/seed<k>/ and reduced_data.{md,csv,json,png}.
    #[arg(long)]
    out: PathBuf,
    /// Grid cells separated by `;`, each `full` or CONDITION=FRACTION[,…] (the training
    /// scenes withheld, see `train --exclude`).
    #[arg(long, default_value = depthsense_experiments::reduced_data::DEFAULT_GRID)]
    grid: String,
    /// Number of seeds: 0, 1, …, N−1.
    #[arg(long, default_value_t = 1)]
    seeds: u64,
}

#[derive(clap::Args)]
pub struct FailureArgs {
    /// Checkpoint to evaluate (depthsense .safetensors, or a .pth with --config).
    #[arg(long)]
    checkpoint: PathBuf,
    /// Architecture for a .pth: a preset or a model-config JSON.
    #[arg(long)]
    config: Option<String>,
    /// Prepared data directory.
    #[arg(long)]
    data: PathBuf,
    /// Output directory for failure.{md,csv,json,png}.
    #[arg(long)]
    out: PathBuf,
    /// Replace results an earlier run of this experiment wrote in --out (only its own
    /// .md/.csv/.json/.png files); without it they are refused before anything is computed.
    #[arg(long)]
    force: bool,
    /// Scenarios separated by `;`; each `none` or settings joined by `,`: radar-drop=F
    /// (fraction of points), drop-radars=A+B (channel names or all), beyond=M (metres),
    /// clutter=N (ghost points per sample).
    #[arg(long, default_value = depthsense_experiments::failure::DEFAULT_SCENARIOS)]
    scenarios: String,
    /// Samples: held-out (test scenes), all, or a split name.
    #[arg(long, default_value = "held-out")]
    split: String,
    /// Seed of the random drop and the clutter.
    #[arg(long, default_value_t = 0)]
    seed: u64,
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
}

#[derive(clap::Args)]
pub struct PerturbArgs {
    /// Checkpoint to evaluate (depthsense .safetensors, or a .pth with --config).
    #[arg(long)]
    checkpoint: PathBuf,
    /// Architecture for a .pth: a preset or a model-config JSON.
    #[arg(long)]
    config: Option<String>,
    /// Prepared data directory (prepared with radar_points.bin: a current `prepare`).
    #[arg(long)]
    data: PathBuf,
    /// Output directory for perturb.{md,csv,json,png}.
    #[arg(long)]
    out: PathBuf,
    /// Replace results an earlier run of this experiment wrote in --out (only its own
    /// .md/.csv/.json/.png files); without it they are refused before anything is computed.
    #[arg(long)]
    force: bool,
    /// Rotation magnitudes in degrees (yaw, pitch, roll), comma separated.
    #[arg(long, value_delimiter = ',', default_value = "0.5,1,2,5")]
    rotate_deg: Vec<f64>,
    /// Translation magnitudes in metres (x, y, z), comma separated.
    #[arg(long, value_delimiter = ',', default_value = "0.1,0.25,0.5")]
    translate_m: Vec<f64>,
    /// Axes, comma separated: yaw (camera vertical), pitch (camera x), roll (optical axis),
    /// x (right), y (down), z (forward).
    #[arg(long, value_delimiter = ',', default_value = "yaw,pitch,roll,x,y,z")]
    axes: Vec<String>,
    /// Samples: held-out (test scenes), all, or a split name.
    #[arg(long, default_value = "held-out")]
    split: String,
    /// Seed of the per-sample sign (+ or − the magnitude).
    #[arg(long, default_value_t = 0)]
    seed: u64,
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
}

#[derive(clap::Args)]
pub struct AblationArgs {
    #[command(flatten)]
    run: RunArgs,
    /// Output directory: runs/<variant>/seed<k>/ and ablation.{md,csv,json,png}.
    #[arg(long)]
    out: PathBuf,
    /// Number of seeds: 0, 1, …, N−1. Each seed trains every variant; the verdicts are a
    /// paired test over the seeds (README "The paper's ablation, with seeds").
    #[arg(long, default_value_t = 5, conflicts_with = "seed_list")]
    seeds: u64,
    /// Explicit seeds instead of --seeds, comma separated (e.g. 0,7,11).
    #[arg(long, value_delimiter = ',')]
    seed_list: Option<Vec<u64>>,
    /// Variants, comma separated: rgb (no radar), early (early fusion), late (late fusion, no
    /// attention), late-sam (late fusion + spatial attention: the paper's model), l1 / l2
    /// (late-sam with an L1 / L2 depth head instead of the ordinal one), late-sam-mer
    /// (late-sam on raw + 6 MER channels; run `depthsense mer apply` on the data first).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "rgb,early,late,late-sam,l1,l2"
    )]
    variants: Vec<String>,
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
        Experiment::ReducedData(a) => reduced_data(a),
        Experiment::Failure(a) => failure(a),
        Experiment::Perturb(a) => perturb(a),
        Experiment::Cost(a) => cost(a),
    }
}

fn cost(a: CostArgs) -> anyhow::Result<ExitCode> {
    use depthsense_experiments::cost::{run_cost, CostOptions, MD_FILE};
    let variants = a
        .variants
        .iter()
        .map(|s| s.parse::<Variant>())
        .collect::<Result<Vec<_>, _>>()?;
    let o = CostOptions {
        presets: a.presets,
        variants,
        batch: a.batch,
        height: a.height,
        width: a.width,
        warmup: a.warmup,
        repeats: a.repeats,
        device: a.device,
        command_line: command_line(),
    };
    let _writing = claim_results(&a.out, "cost", a.force)?;
    let pb = super::train::progress_bar("cost");
    run_cost(&o, &a.out, &pb)?;
    pb.finish_and_clear();
    println!("{}", std::fs::read_to_string(a.out.join(MD_FILE))?);
    Ok(ExitCode::SUCCESS)
}

/// The results-folder rule for `experiment NAME` (README "Reliability"): the folder's lock,
/// and OUT/NAME.{md,csv,json,png} refused when present unless --force.
fn claim_results(
    out: &std::path::Path,
    name: &str,
    force: bool,
) -> anyhow::Result<depthsense_nuscenes::lock::OutputLock> {
    let lock = depthsense_nuscenes::lock::OutputLock::exclusive(
        out,
        &format!("depthsense experiment {name}"),
    )?;
    let files: Vec<PathBuf> = ["md", "csv", "json", "png"]
        .iter()
        .map(|e| out.join(format!("{name}.{e}")))
        .collect();
    depthsense_train::outputs::refuse_existing(&files, force, &format!("experiment {name}"))?;
    Ok(lock)
}

fn command_line() -> Option<String> {
    Some(std::env::args().collect::<Vec<_>>().join(" "))
}

fn reduced_data(a: ReducedDataArgs) -> anyhow::Result<ExitCode> {
    use depthsense_experiments::reduced_data::{
        parse_grid, run_reduced_data, ReducedDataOptions, MD_FILE,
    };
    let opts = ReducedDataOptions {
        run: a.run.settings(),
        out: a.out,
        grid: parse_grid(&a.grid)?,
        seeds: (0..a.seeds).collect(),
        eval: EvalConfig::default(),
        command_line: command_line(),
    };
    let r = run_reduced_data(&opts, &MultiProgress::new())?;
    let md = std::fs::read_to_string(opts.out.join(MD_FILE))?;
    println!("{md}");
    eprintln!("{} runs in {:.1} s", r.runs.len(), r.total_seconds);
    Ok(ExitCode::SUCCESS)
}

fn failure(a: FailureArgs) -> anyhow::Result<ExitCode> {
    use depthsense_eval::evaluate::EvalOptions;
    use depthsense_experiments::failure::{parse_scenarios, run_failure, FAILURE_MD};
    let base = EvalOptions {
        checkpoint: a.checkpoint,
        config: a.config,
        data: a.data,
        split: a.split,
        seed: a.seed,
        batch_size: a.batch_size,
        device: a.device,
        jobs: a.jobs,
        max_samples: a.max_samples,
        ..EvalOptions::default()
    };
    let sc = parse_scenarios(&a.scenarios)?;
    let _writing = claim_results(&a.out, "failure", a.force)?;
    run_failure(&base, &sc, &a.out, command_line(), &MultiProgress::new())?;
    println!("{}", std::fs::read_to_string(a.out.join(FAILURE_MD))?);
    Ok(ExitCode::SUCCESS)
}

fn perturb(a: PerturbArgs) -> anyhow::Result<ExitCode> {
    use depthsense_eval::evaluate::EvalOptions;
    use depthsense_experiments::perturb::{parse_axes, run_perturb, PerturbOptions, PERTURB_MD};
    let base = EvalOptions {
        checkpoint: a.checkpoint,
        config: a.config,
        data: a.data,
        split: a.split,
        seed: a.seed,
        batch_size: a.batch_size,
        device: a.device,
        jobs: a.jobs,
        max_samples: a.max_samples,
        ..EvalOptions::default()
    };
    let opts = PerturbOptions {
        rotate_deg: a.rotate_deg,
        translate_m: a.translate_m,
        axes: parse_axes(&a.axes)?,
    };
    let _writing = claim_results(&a.out, "perturb", a.force)?;
    let t = std::time::Instant::now();
    run_perturb(&base, &opts, &a.out, command_line(), &MultiProgress::new())?;
    println!("{}", std::fs::read_to_string(a.out.join(PERTURB_MD))?);
    eprintln!("{:.1} s", t.elapsed().as_secs_f64());
    Ok(ExitCode::SUCCESS)
}

fn ablation(a: AblationArgs) -> anyhow::Result<ExitCode> {
    let opts = ablation_options(a)?;
    let mp = MultiProgress::new();
    let r = run_ablation(&opts, &mp)?;
    print_ablation(&r, &opts);
    Ok(ExitCode::SUCCESS)
}

/// The ablation's options: variants (empty names skipped), seeds (--seed-list, else
/// 0..--seeds) and the test protocol and aggregation.
fn ablation_options(a: AblationArgs) -> anyhow::Result<AblationOptions> {
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
    Ok(AblationOptions {
        run: a.run.settings(),
        out: a.out,
        variants,
        seeds,
        eval: EvalConfig {
            protocol: a.protocol.parse::<Protocol>()?,
            aggregate: a.aggregate.parse::<Aggregate>()?,
            ..EvalConfig::default()
        },
        command_line: command_line(),
    })
}

/// The combined test metrics per variant and the verdicts (stdout), then what was run and
/// where the report is (stderr).
fn print_ablation(r: &AblationResult, opts: &AblationOptions) {
    println!(
        "{:<10} {:>3}  {:>17}  {:>17}  {:>17}",
        "variant", "n", "test RMSE (m)", "δ1", "AbsRel"
    );
    for (name, _) in &r.models {
        let row = r.row(name, "combined", "full");
        let f = |s: Option<depthsense_experiments::Stat>| s.map_or("–".into(), |s| s.fmt(3));
        println!(
            "{:<10} {:>3}  {:>17}  {:>17}  {:>17}",
            name,
            row.map_or(0, |x| x.n),
            f(row.and_then(|x| x.rmse)),
            f(row.and_then(|x| x.delta1)),
            f(row.and_then(|x| x.abs_rel)),
        );
    }
    for v in &r.verdicts {
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
}
