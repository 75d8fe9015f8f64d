//! `depthsense train`: train a depth network on prepared data (SPEC §8). (the network side; its flags: `depthsense_cli::cmd::train`).

use depthsense_cli::cmd::progress::progress_bar;
/// This process's arguments without `--nproc N` (what each worker runs).
use depthsense_cli::cmd::train::Args;
use depthsense_cli::stop::invocation;
use depthsense_config::training::DistributedOptions;
use depthsense_config::RadarInput;
use depthsense_config::{Fusion, ModelConfig};
use depthsense_dist::DistEnv;
use depthsense_metrics::EvalConfig;
use depthsense_progress::Progress;
use depthsense_train::distributed::{self, Dist, DistOptions};
use depthsense_train::trainer::{train, train_distributed, TrainOptions, TrainSummary};
use std::ffi::OsString;
use std::process::ExitCode;
use std::time::Duration;

fn worker_args() -> Vec<OsString> {
    let mut out = vec![];
    let mut it = std::env::args_os().skip(1);
    while let Some(a) = it.next() {
        if a == "--nproc" {
            it.next();
        } else if a.to_string_lossy().starts_with("--nproc=") {
        } else {
            out.push(a);
        }
    }
    out
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    if let Some(n) = a.distributed.nproc {
        return launch_workers(&a, n);
    }
    let dist = a.distributed.clone();
    let out = a.out.clone();
    let cuda = match a.hardware.device.name.as_str() {
        "cpu" => false,
        d if d.starts_with("cuda") => true,
        _ => tch::Cuda::is_available(),
    };
    if let Some(note) = depthsense_cli::cmd::train::default_network_note(&invocation(), cuda) {
        eprintln!("{note}");
    }
    let model = model_config(&a)?;
    let opts = train_options(a, model)?;
    depthsense_cli::stop::catch_stop_signals()?;
    let trained = train_this_process(opts, &dist)?;
    let Some((s, pb)) = trained else {
        // a rank other than 0: rank 0 reports
        return Ok(depthsense_base::interrupt::requested()
            .map_or(ExitCode::SUCCESS, |sig| ExitCode::from(sig.exit_code())));
    };
    // `--resume` of a finished run: said, nothing to do.
    if let Some(finished) = &s.already_finished {
        pb.finish_and_clear();
        eprintln!("{finished}");
        return Ok(ExitCode::SUCCESS);
    }
    pb.finish();
    print_summary(&s, &out);
    if let Some(sig) = s.signal {
        return Ok(depthsense_cli::stop::interrupted(
            sig,
            s.iterations_done,
            s.total_iterations,
        ));
    }
    Ok(ExitCode::SUCCESS)
}

/// `--nproc N`: refuse a used run folder before any worker starts, then run N local workers
/// (each this command without `--nproc`) and wait for them.
fn launch_workers(a: &Args, n: usize) -> anyhow::Result<ExitCode> {
    // Refused before any worker starts (rank 0 checks again and takes the folder's lock).
    let c = &a.checkpointing;
    if !c.resume && !a.extension.extend && !c.force {
        depthsense_dataset::outputs::claim_run_folder(&a.out, "train", false, false)?;
    }
    // Another writer fails us here, at once (taken and released: rank 0 holds it next).
    drop(depthsense_base::lock::OutputLock::exclusive(
        &a.out,
        "depthsense train",
    )?);
    // The workers record and print this command (with --nproc), not their own.
    let words = serde_json::to_string(&depthsense_cli::stop::invocation())?;
    std::env::set_var(depthsense_cli::stop::INVOCATION_ENV, words);
    depthsense_cli::stop::catch_stop_signals()?;
    let stopped = depthsense_dist::launch::launch_local(
        n,
        &worker_args(),
        a.distributed.master_port,
        a.distributed.timeout() + Duration::from_secs(30),
    )?;
    // Rank 0 printed where it stopped and how to continue.
    Ok(stopped.map_or(ExitCode::SUCCESS, |sig| ExitCode::from(sig.exit_code())))
}

/// The preset with the command line's model options applied, `--set` last.
fn model_config(a: &Args) -> anyhow::Result<ModelConfig> {
    let mut model = depthsense_checkpoint::config::resolve(&a.config)?;
    if let Some(f) = &a.fusion {
        model.apply_option("fusion", f)?;
        if model.fusion != Fusion::Late {
            model.attention = false;
        }
    }
    if let Some(h) = &a.head {
        model.apply_option("head", h)?;
    }
    if let Some(d) = a.dropout {
        model.dropout = d;
    }
    if a.no_attention {
        model.attention = false;
    }
    if let Some(r) = &a.radar_input {
        // The radar input fixes the channel count (mer: raw + 6 MER = 7, SPEC §5).
        model.set_option("radar-input", r)?;
    }
    Ok(model.with_options(&a.set)?)
}

/// The trainer's options from the command line and the resolved `model`: the option groups
/// move over as they were parsed.
fn train_options(a: Args, model: ModelConfig) -> anyhow::Result<TrainOptions> {
    Ok(TrainOptions {
        data: a.data,
        out: a.out,
        command: depthsense_cli::stop::invocation(),
        model,
        schedule: a.schedule,
        loading: a.loading,
        validation: a.validation,
        checkpointing: a.checkpointing,
        extension: a.extension,
        hardware: a.hardware,
        backbone_weights: a.backbone_weights,
        init_from: a.init_from,
        radar_input: a
            .radar_input
            .as_deref()
            .map(str::parse::<RadarInput>)
            .transpose()?,
        exclude: a
            .exclude
            .iter()
            .map(|x| x.parse::<depthsense_data::exclusion::Exclusion>())
            .collect::<Result<Vec<_>, _>>()?,
        eval: EvalConfig {
            protocol: a.scoring.protocol,
            aggregate: a.scoring.aggregate,
            ..EvalConfig::default()
        },
    })
}

/// Train in this process: alone, or as one rank of the job the environment describes.
/// `None` on ranks other than 0 (they print nothing).
fn train_this_process(
    mut opts: TrainOptions,
    d: &DistributedOptions,
) -> anyhow::Result<Option<(TrainSummary, Progress)>> {
    let env = match DistEnv::from_env()? {
        None => {
            if d.sync_bn {
                eprintln!("note: --sync-bn has no effect in a single process");
            }
            let pb = progress_bar("train");
            return Ok(Some((train(&opts, &pb)?, pb)));
        }
        Some(env) => env,
    };
    let device_name = &mut opts.hardware.device.name;
    *device_name = distributed::device_for_local_rank(device_name, env.local_rank);
    let device = depthsense_model::device::parse_device(device_name)?;
    let dopts = DistOptions {
        sync_bn: d.sync_bn,
        bucket_bytes: d.bucket_bytes(),
        check_replicas: d.check_replicas,
    };
    let who = format!("rank {} of {}", env.rank, env.world_size);
    let dist = Dist::from_env(dopts, device, d.timeout())
        .map_err(|e| anyhow::anyhow!("{who}: {e}"))?
        .ok_or_else(|| anyhow::anyhow!("{who}: the distributed environment vanished"))?;
    let pb = if env.rank == 0 {
        progress_bar("train")
    } else {
        Progress::hidden()
    };
    let s = train_distributed(&opts, dist, &pb).map_err(|e| anyhow::anyhow!("{who}: {e}"))?;
    if env.rank != 0 {
        return Ok(None);
    }
    Ok(Some((s, pb)))
}

/// The run's summary on stderr: iterations, times, validation RMSE over the whole history.
fn print_summary(s: &TrainSummary, out: &std::path::Path) {
    // The whole history (a resumed run's summary only holds its own epochs).
    let history = depthsense_train::metrics_log::read_metrics(
        &out.join(depthsense_dataset::outputs::METRICS_FILE),
    )
    .map(|(_, v)| v)
    .unwrap_or_else(|_| s.val.clone());
    let first = history.first().map_or(f64::NAN, |v| v.rmse);
    let last = history.last().map_or(f64::NAN, |v| v.rmse);
    eprintln!(
        "{} iterations of {} in {:.1} s (training {:.1} s at {:.2} img/s, validation {:.1} s, \
         the rest set-up and checkpoints); validation RMSE {first:.3} m → {last:.3} m \
         (best {}) on {} validation samples{} ({})",
        s.iterations_done,
        s.total_iterations,
        s.seconds,
        s.train_seconds,
        s.train_images_per_s,
        s.val_seconds,
        if s.best_val_rmse.is_finite() {
            format!("{:.3} m", s.best_val_rmse)
        } else {
            "none yet: no validation finished".to_string()
        },
        s.val_samples_used,
        if s.val_samples_used < s.partition.val.len() {
            format!(" of {}", s.partition.val.len())
        } else {
            String::new()
        },
        s.partition.method
    );
    eprintln!("{}", s.best);
    if s.interrupted && s.signal.is_none() {
        eprintln!(
            "stopped at iteration {} as asked; continue with --resume",
            s.iterations_done
        );
    }
    eprintln!("run directory: {}", out.display());
}
