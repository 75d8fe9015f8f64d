//! `depthsense eval`: the paper's tables (SPEC §10 items 1–3) for a checkpoint, or for any (the network side; its flags: `depthsense_cli::cmd::eval`).

use depthsense_cli::cmd::eval::{eval_config, model_name, Args};
use depthsense_cli::cmd::progress::progress_bar;
use depthsense_cli::command_line;
use depthsense_data::radar_failure::RadarFailure;
use depthsense_dataset::outputs::refuse_existing;
use depthsense_eval::evaluate::{load_model, run_eval_loaded, EvalOptions};
use depthsense_score::tables::{table_paths, write_tables_with_command};
use std::path::PathBuf;
use std::process::ExitCode;

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let checkpoint = a
        .checkpoint
        .clone()
        .ok_or_else(|| anyhow::anyhow!("give --checkpoint or --predictions"))?;
    let out = a.out.clone().unwrap_or_else(|| {
        checkpoint
            .parent()
            .map(|p| p.join("eval"))
            .unwrap_or_else(|| PathBuf::from("eval"))
    });
    refuse_existing(&table_paths(&out), a.force, "eval")?;
    let name = model_name(&a);
    let opts = EvalOptions {
        checkpoint,
        config: a.config.clone(),
        set: a.set.clone(),
        data: a.data.clone(),
        split: a.split.clone(),
        val_every_scene: a.val_every_scene,
        eval: eval_config(&a)?,
        radar_drop: a.radar_drop,
        failure: RadarFailure {
            drop_radars: a.drop_radars.clone(),
            drop_beyond_m: a.drop_beyond_m,
            clutter: a.clutter,
            perturb: None,
        },
        seed: a.seed,
        batch_size: a.run.batch_size,
        device: a.run.device.name.clone(),
        jobs: a.run.jobs,
        max_samples: a.run.max_samples,
        radar_input: a.radar_input.as_deref().map(str::parse).transpose()?,
        name: name.clone(),
        cuda_graph: a.run.cuda_graph,
    };
    let device = depthsense_model::device::parse_device(&opts.device)?;
    let (loaded, load_report) =
        load_model(&opts.checkpoint, opts.config.as_deref(), &opts.set, device)?;
    if let Some(r) = &load_report {
        eprint!("{}: {r}", opts.checkpoint.display());
    }
    let pb = progress_bar("eval");
    let report = run_eval_loaded(&opts, &loaded, &pb)?;
    pb.finish_and_clear();
    let models = [(name.as_str(), &report)];
    write_tables_with_command(&out, &models, Some(&command_line()))?;
    println!("{}", depthsense_metrics::tables::markdown_report(&models));
    eprintln!(
        "{} images evaluated (radar drop {}, failure: {}); tables written to {}/tables.{{md,csv,json}}",
        report.images_seen,
        opts.radar_drop,
        opts.failure.label(),
        out.display()
    );
    Ok(ExitCode::SUCCESS)
}
