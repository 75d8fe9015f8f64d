//! `depthsense experiment …`: SPEC §10 experiments built from training runs. (the network side; its flags: `depthsense_cli::cmd::experiment`).

use depthsense_cli::cmd::experiment::{
    AblationArgs, Args, CostArgs, DataScaleArgs, Experiment, FailureArgs, PerturbArgs,
    ReducedDataArgs, RunArgs,
};
use depthsense_cli::cmd::inference_args::InferenceArgs;
use depthsense_cli::cmd::model_source::ModelSource;
use depthsense_cli::cmd::progress::progress_bar;
use depthsense_config::training::{
    HardwareOptions, LoadingOptions, ScheduleOptions, ValidationOptions,
};
use depthsense_experiments::ablation::{
    run_ablation, AblationOptions, AblationResult, MD_FILE, PNG_FILE,
};
use depthsense_experiments::runner::RunSettings;
use depthsense_metrics::EvalConfig;
use depthsense_progress::Board;
use std::path::PathBuf;
use std::process::ExitCode;

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    match a.command {
        Experiment::Ablation(a) => ablation(a),
        Experiment::ReducedData(a) => reduced_data(a),
        Experiment::DataScale(a) => data_scale(a),
        Experiment::Failure(a) => failure(a),
        Experiment::Perturb(a) => perturb(a),
        Experiment::Cost(a) => cost(a),
    }
}

fn cost(a: CostArgs) -> anyhow::Result<ExitCode> {
    use depthsense_experiments::cost::{run_cost, CostOptions, MD_FILE};
    let o = CostOptions {
        presets: a.configs,
        variants: a.variants,
        batch: a.batch,
        height: a.height,
        width: a.width,
        warmup: a.warmup_runs,
        repeats: a.repeats,
        device: a.device.name,
        command_line: command_line(),
    };
    let _writing = claim_results(&a.out, "cost", a.force)?;
    let pb = progress_bar("cost");
    run_cost(&o, &a.out, &pb)?;
    pb.finish_and_clear();
    println!("{}", std::fs::read_to_string(a.out.join(MD_FILE))?);
    Ok(ExitCode::SUCCESS)
}

/// The results-folder rule for `experiment NAME` (docs/guide/reliability.md): the folder's lock,
/// and OUT/NAME.{md,csv,json,png} refused when present unless --force.
fn claim_results(
    out: &std::path::Path,
    name: &str,
    force: bool,
) -> anyhow::Result<depthsense_base::lock::OutputLock> {
    let lock = depthsense_base::lock::OutputLock::exclusive(
        out,
        &format!("depthsense experiment {name}"),
    )?;
    let files: Vec<PathBuf> = ["md", "csv", "json", "png"]
        .iter()
        .map(|e| out.join(format!("{name}.{e}")))
        .collect();
    depthsense_dataset::outputs::refuse_existing(&files, force, &format!("experiment {name}"))?;
    Ok(lock)
}

fn command_line() -> Option<String> {
    Some(depthsense_cli::command_line())
}

fn reduced_data(a: ReducedDataArgs) -> anyhow::Result<ExitCode> {
    use depthsense_experiments::reduced_data::{
        parse_grid, run_reduced_data, ReducedDataOptions, MD_FILE,
    };
    let opts = ReducedDataOptions {
        run: run_settings(a.run),
        out: a.out,
        grid: parse_grid(&a.grid)?,
        seeds: (0..a.seeds).collect(),
        eval: EvalConfig::default(),
        command_line: command_line(),
    };
    let r = run_reduced_data(&opts, &Board::new(16))?;
    let md = std::fs::read_to_string(opts.out.join(MD_FILE))?;
    println!("{md}");
    eprintln!("{} runs in {:.1} s", r.runs.len(), r.total_seconds);
    Ok(ExitCode::SUCCESS)
}

fn data_scale(a: DataScaleArgs) -> anyhow::Result<ExitCode> {
    use depthsense_experiments::data_scale::{run_data_scale, Arm, DataScaleOptions, MD_FILE};
    let arms = |v: &[String]| -> anyhow::Result<Vec<Arm>> {
        Ok(v.iter()
            .map(|s| s.parse::<Arm>())
            .collect::<Result<_, _>>()?)
    };
    let opts = DataScaleOptions {
        run: run_settings(a.run),
        out: a.out,
        sizes: a.sizes,
        arms: arms(&a.arms)?,
        at_largest: arms(&a.at_largest)?,
        seeds: a.seed_list.unwrap_or_else(|| (0..a.seeds).collect()),
        iterations: a.iterations,
        eval: EvalConfig::default(),
        command_line: command_line(),
    };
    let r = run_data_scale(&opts, &Board::new(16))?;
    println!("{}", std::fs::read_to_string(opts.out.join(MD_FILE))?);
    eprintln!("{} runs in {:.1} s", r.runs.len(), r.total_seconds);
    Ok(ExitCode::SUCCESS)
}

/// The evaluation an experiment varies (failure, perturb): its network, samples and inference
/// flags.
fn evaluation(
    model: ModelSource,
    data: std::path::PathBuf,
    split: String,
    seed: u64,
    run: InferenceArgs,
) -> depthsense_eval::evaluate::EvalOptions {
    depthsense_eval::evaluate::EvalOptions {
        checkpoint: model.checkpoint,
        config: model.config,
        set: model.set,
        data,
        split,
        seed,
        batch_size: run.batch_size,
        device: run.device.name,
        jobs: run.jobs,
        max_samples: run.max_samples,
        cuda_graph: run.cuda_graph,
        ..Default::default()
    }
}

fn failure(a: FailureArgs) -> anyhow::Result<ExitCode> {
    use depthsense_experiments::failure::{parse_scenarios, run_failure, FAILURE_MD};
    let base = evaluation(a.model, a.data, a.split, a.seed, a.run);
    let sc = parse_scenarios(&a.scenarios)?;
    let _writing = claim_results(&a.out, "failure", a.force)?;
    run_failure(&base, &sc, &a.out, command_line(), &Board::new(16))?;
    println!("{}", std::fs::read_to_string(a.out.join(FAILURE_MD))?);
    Ok(ExitCode::SUCCESS)
}

fn perturb(a: PerturbArgs) -> anyhow::Result<ExitCode> {
    use depthsense_experiments::perturb::{run_perturb, PerturbOptions, PERTURB_MD};
    let base = evaluation(a.model, a.data, a.split, a.seed, a.run);
    let opts = PerturbOptions {
        rotate_deg: a.rotate_deg,
        translate_m: a.translate_m,
        axes: a.axes,
    };
    let _writing = claim_results(&a.out, "perturb", a.force)?;
    let t = std::time::Instant::now();
    run_perturb(&base, &opts, &a.out, command_line(), &Board::new(16))?;
    println!("{}", std::fs::read_to_string(a.out.join(PERTURB_MD))?);
    eprintln!("{:.1} s", t.elapsed().as_secs_f64());
    Ok(ExitCode::SUCCESS)
}

fn ablation(a: AblationArgs) -> anyhow::Result<ExitCode> {
    let opts = ablation_options(a)?;
    let mp = Board::new(16);
    let r = run_ablation(&opts, &mp)?;
    print_ablation(&r, &opts);
    Ok(ExitCode::SUCCESS)
}

/// The ablation's options: variants, seeds (--seed-list, else 0..--seeds) and the test
/// protocol and aggregation.
fn ablation_options(a: AblationArgs) -> anyhow::Result<AblationOptions> {
    let variants = a.variants;
    let seeds = match a.seed_list {
        Some(l) => l,
        None => (0..a.seeds).collect(),
    };
    Ok(AblationOptions {
        run: run_settings(a.run),
        out: a.out,
        variants,
        seeds,
        eval: EvalConfig {
            protocol: a.scoring.protocol,
            aggregate: a.scoring.aggregate,
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

/// The shared training settings of an experiment's runs: `train`'s option groups with the
/// experiments' flags, the rest at `train`'s defaults.
fn run_settings(a: RunArgs) -> RunSettings {
    RunSettings {
        data: a.data,
        preset: a.config,
        set: a.set,
        schedule: ScheduleOptions {
            epochs: a.epochs,
            batch_size: a.batch_size,
            lr: a.lr,
            max_batches_per_epoch: a.max_batches_per_epoch,
            warmup_iters: a.warmup,
            epoch_iterations: a.epoch_iterations,
            ..ScheduleOptions::default()
        },
        loading: LoadingOptions {
            jobs: a.jobs,
            train_radar_drop: a.train_radar_drop,
            ..LoadingOptions::default()
        },
        validation: ValidationOptions {
            max_val_samples: a.max_val_samples,
            val_every_scene: a.val_every_scene,
        },
        hardware: HardwareOptions {
            device: a.device,
            ..HardwareOptions::default()
        },
    }
}
