//! `depthsense mer train | apply | report`: MER, the multi-channel enhanced radar (SPEC §5). (the network side; its flags: `depthsense_cli::cmd::mer`).

use depthsense_cli::cmd::mer::{ApplyArgs, Args, Command, TrainArgs};
use depthsense_cli::cmd::progress::progress_bar;
use depthsense_config::pda::PdaConfig;
use depthsense_mer::apply::{apply, MerApplyOptions};
use depthsense_mer_train::{train_pda, MerTrainOptions, MerTrainSummary};
use std::process::ExitCode;

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    match a.command {
        Command::Train(t) => run_train(t),
        Command::Apply(x) => run_apply(x),
        Command::Report(r) => depthsense_cli::cmd::mer::run_report(r),
    }
}

fn run_train(a: TrainArgs) -> anyhow::Result<ExitCode> {
    let opts = train_options(a)?;
    depthsense_cli::stop::catch_stop_signals()?;
    let pb = progress_bar("mer");
    let s = train_pda(&opts, &pb)?;
    pb.finish_and_clear();
    print_summary(&opts, &s);
    if let Some(sig) = s.signal {
        return Ok(depthsense_cli::stop::interrupted(
            sig,
            s.iterations,
            s.total_iterations,
        ));
    }
    if s.interrupted {
        eprintln!(
            "stopped at iteration {} as asked; continue with --resume",
            s.iterations
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// The options of `mer train` from its flags (`--affinity` overrides the preset's affinity
/// channels, checked).
fn train_options(a: TrainArgs) -> anyhow::Result<MerTrainOptions> {
    Ok(MerTrainOptions {
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
        schedule: a.schedule,
        loading: a.loading,
        validation: a.validation,
        checkpointing: a.checkpointing,
        device: a.device,
        command: depthsense_cli::stop::invocation(),
    })
}

/// Every validation of the run and its summary line (best AUC, iterations, seconds, folder).
fn print_summary(opts: &MerTrainOptions, s: &MerTrainSummary) {
    for v in &s.val {
        eprintln!(
            "epoch {:>3}: val loss {:.4} precision {:.3} recall {:.3} AUC {:.3} ({} pairs, {} positive)",
            v.epoch, v.loss, v.precision, v.recall, v.auc, v.pairs, v.positives
        );
    }
    eprintln!(
        "PDA {} ({} parameters): best val AUC {:.3}{}, {} iterations in {:.1} s → {}",
        opts.pda.name,
        s.parameters,
        s.best_auc,
        match s.best_iteration {
            Some(0) => " (best.safetensors: the network before training)".to_string(),
            Some(it) => format!(" (best.safetensors: iteration {it})"),
            None => String::new(),
        },
        s.iterations,
        s.seconds,
        s.run_dir.display()
    );
}

fn run_apply(a: ApplyArgs) -> anyhow::Result<ExitCode> {
    let opts = MerApplyOptions {
        data: a.data,
        checkpoint: a.checkpoint,
        device: a.device.name,
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
