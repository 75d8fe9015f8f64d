//! Training (SPEC §8): SGD with momentum, poly learning-rate decay per iteration, validation
//! each epoch, atomic checkpoints, exact resume, non-finite-loss stop.
//!
//! `RUN/` layout:
//! ```text
//! RUN/config.json            TrainOptions + ModelConfig + partition (held-out scenes)
//! RUN/metrics.jsonl          {"kind":"iter",…} per iteration, {"kind":"epoch",…} per epoch
//! RUN/curves.png             training loss and validation RMSE curves
//! RUN/last.safetensors       latest checkpoint (+ last.optim.safetensors: momentum buffers)
//! RUN/best.safetensors       lowest validation RMSE so far
//! ```

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use depthsense_metrics::{EvalConfig, Evaluator, Report};
use depthsense_model::{checkpoint, DepthNet, Fusion, ModelConfig};
use depthsense_nuscenes::fsutil::write_atomic;
use depthsense_prep::layout::IndexEntry;
use indicatif::ProgressBar;
use serde::{Deserialize, Serialize};
use tch::{nn::VarStore, Device, Kind, Tensor};

use crate::data::{
    mix64, partition, Batch, Dataset, EpochPlan, LoadOptions, Loader, Partition, RadarInput,
    TargetKind,
};
use crate::error::TrainError;
use crate::sgd::{poly_lr, Sgd};

pub const CONFIG_FILE: &str = "config.json";
pub const METRICS_FILE: &str = "metrics.jsonl";
pub const CURVES_FILE: &str = "curves.png";
pub const LAST_CKPT: &str = "last.safetensors";
pub const LAST_OPTIM: &str = "last.optim.safetensors";
pub const BEST_CKPT: &str = "best.safetensors";

/// Everything a training run is made of. Defaults are the paper's (SPEC §8).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainOptions {
    pub data: PathBuf,
    pub out: PathBuf,
    pub model: ModelConfig,
    pub epochs: usize,
    pub batch_size: usize,
    pub lr: f64,
    /// Power of the polynomial decay (0.9).
    pub lr_power: f64,
    pub momentum: f64,
    pub weight_decay: f64,
    pub seed: u64,
    /// auto | cpu | cuda | cuda:N
    pub device: String,
    /// bf16 autocast of the forward pass (CUDA only).
    pub amp: bool,
    /// torchvision ResNet state dict for the RGB encoder (ImageNet initialisation).
    pub backbone_weights: Option<PathBuf>,
    /// Continue from RUN/last.safetensors.
    pub resume: bool,
    /// Loader threads (0 = all cores) and batches decoded ahead.
    pub jobs: usize,
    pub prefetch: usize,
    /// Radar map(s) feeding the radar channels (None = derive from the model config).
    pub radar_input: Option<RadarInput>,
    pub target: TargetKind,
    /// SPEC §8 augmentation.
    pub augment: bool,
    /// Without train/test split lists, every N-th scene (sorted by name) is held out.
    pub val_every_scene: usize,
    /// Use at most this many validation samples (evenly spaced), None = all.
    pub max_val_samples: Option<usize>,
    /// Use at most this many batches per epoch, None = all (quick runs).
    pub max_batches_per_epoch: Option<usize>,
    /// Save RUN/last.safetensors every N iterations as well as at each epoch end (0 = never).
    pub checkpoint_every: u64,
    /// Stop (after checkpointing) when this global iteration is reached — an interruption
    /// that `--resume` continues from exactly.
    pub stop_after: Option<u64>,
    /// Validation metric settings (caps, protocol, aggregation).
    pub eval: EvalConfig,
}

impl Default for TrainOptions {
    fn default() -> Self {
        Self {
            data: PathBuf::from("prepared"),
            out: PathBuf::from("runs/train"),
            model: ModelConfig::paper(),
            epochs: 40,
            batch_size: 8,
            lr: 1e-3,
            lr_power: 0.9,
            momentum: 0.9,
            weight_decay: 1e-4,
            seed: 0,
            device: "auto".into(),
            amp: false,
            backbone_weights: None,
            resume: false,
            jobs: 0,
            prefetch: 4,
            radar_input: None,
            target: TargetKind::Dense,
            augment: true,
            val_every_scene: 5,
            max_val_samples: None,
            max_batches_per_epoch: None,
            checkpoint_every: 0,
            stop_after: None,
            eval: EvalConfig::default(),
        }
    }
}

/// One validation result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValRecord {
    pub epoch: u64,
    pub iteration: u64,
    pub rmse: f64,
    pub mae: f64,
    pub abs_rel: f64,
    pub delta1: f64,
    pub n_images: u64,
    pub n_pixels: u64,
}

impl ValRecord {
    fn from_report(epoch: u64, iteration: u64, r: &Report) -> Self {
        let row = r.headline().cloned();
        let m = row.as_ref().map(|r| r.metrics).unwrap_or_default();
        Self {
            epoch,
            iteration,
            rmse: m.rmse,
            mae: m.mae,
            abs_rel: m.abs_rel,
            delta1: m.delta1,
            n_images: row.as_ref().map_or(0, |r| r.n_images),
            n_pixels: row.as_ref().map_or(0, |r| r.n_pixels),
        }
    }
}

/// What a (possibly partial) training invocation did.
#[derive(Debug, Clone)]
pub struct TrainSummary {
    pub run_dir: PathBuf,
    /// (global iteration, loss) of the iterations run by this invocation.
    pub losses: Vec<(u64, f64)>,
    /// Validation before training (iteration 0, when not resuming) and after each epoch.
    pub val: Vec<ValRecord>,
    pub iterations_done: u64,
    pub total_iterations: u64,
    /// True when `stop_after` interrupted the run.
    pub interrupted: bool,
    pub best_val_rmse: f64,
    pub train_images_per_s: f64,
    pub seconds: f64,
    pub partition: Partition,
}

/// Training state stored in a checkpoint's `extra` (with the options that must not change
/// across a resume).
#[derive(Debug, Clone, Serialize, Deserialize)]
struct State {
    kind: String,
    iteration: u64,
    epoch: u64,
    seed: u64,
    /// Lowest validation RMSE so far; `None` before the first epoch ends (JSON has no ∞).
    best_val_rmse: Option<f64>,
    batch_size: usize,
    epochs: usize,
    lr: f64,
    val_rmse: Option<f64>,
}

/// Radar input for a model config (fusion None → no radar).
pub fn radar_input_for(
    cfg: &ModelConfig,
    requested: Option<RadarInput>,
) -> Result<Option<RadarInput>, TrainError> {
    if cfg.fusion == Fusion::None {
        return Ok(None);
    }
    let r = match requested {
        Some(r) => r,
        None => RadarInput::for_channels(cfg.radar_channels)?,
    };
    if r.channels() as i64 != cfg.radar_channels {
        return Err(TrainError::Config(format!(
            "radar input {r:?} has {} channel(s) but the model expects radar_channels = {}",
            r.channels(),
            cfg.radar_channels
        )));
    }
    Ok(Some(r))
}

/// Tensors of a batch on `device`: (image [B,3,H,W], radar [B,C,H,W] (C ≥ 1; zeros when the
/// batch has no radar), target [B,1,H,W]).
pub fn batch_tensors(b: &Batch, device: Device) -> (Tensor, Tensor, Tensor) {
    let (n, h, w) = (b.size as i64, b.height as i64, b.width as i64);
    let image = Tensor::from_slice(&b.image)
        .view([n, 3, h, w])
        .to_device(device);
    let radar = if b.radar_channels == 0 {
        Tensor::zeros([n, 1, h, w], (Kind::Float, device))
    } else {
        Tensor::from_slice(&b.radar)
            .view([n, b.radar_channels as i64, h, w])
            .to_device(device)
    };
    let target = Tensor::from_slice(&b.target_m)
        .view([n, 1, h, w])
        .to_device(device);
    (image, radar, target)
}

/// Evenly spaced subset of at most `max` entries (deterministic).
pub fn subsample(entries: &[IndexEntry], max: Option<usize>) -> Vec<IndexEntry> {
    match max {
        Some(m) if m > 0 && entries.len() > m => (0..m)
            .map(|i| entries[i * entries.len() / m].clone())
            .collect(),
        _ => entries.to_vec(),
    }
}

/// Run `net` over `entries` and feed the decoded depth to the metrics (SPEC §9). `on_batch`
/// sees every batch with its predictions ([B,H,W] metres, row-major).
#[allow(clippy::too_many_arguments)]
pub fn evaluate_net(
    net: &DepthNet,
    ds: &Dataset,
    entries: &[IndexEntry],
    load: &LoadOptions,
    eval_cfg: &EvalConfig,
    batch_size: usize,
    jobs: usize,
    device: Device,
    progress: &ProgressBar,
    mut on_batch: impl FnMut(&Batch, &[f32]) -> Result<(), TrainError>,
) -> Result<Report, TrainError> {
    let mut ev = Evaluator::new(eval_cfg.clone())?;
    let mut load = load.clone();
    load.eval_maps = true;
    load.augment = false;
    load.target = TargetKind::Sparse;
    let plan = EpochPlan {
        entries: entries.to_vec(),
        batch_size: batch_size.max(1),
        epoch: 0,
        shuffle: false,
        drop_last: false,
        skip_batches: 0,
        jobs,
        prefetch: 2,
    };
    for batch in Loader::start(ds, &load, &plan)? {
        let batch = batch?;
        let (image, radar, _) = batch_tensors(&batch, device);
        let pred = tch::no_grad(|| {
            let out = net.forward_t(&image, &radar, false);
            net.decode(&out)
        });
        let pred = pred
            .to_device(Device::Cpu)
            .to_kind(Kind::Float)
            .contiguous();
        let hw = batch.width * batch.height;
        let pred_shape = pred.size();
        if pred.numel() != batch.size * hw {
            return Err(TrainError::Other(format!(
                "decoded prediction has shape {pred_shape:?}, expected [{}, 1, {}, {}]",
                batch.size, batch.height, batch.width
            )));
        }
        let pred_v: Vec<f32> = Vec::<f32>::try_from(pred.view([-1]))?;
        for (i, s) in batch.samples.iter().enumerate() {
            let conds: Vec<&str> = s
                .conditions
                .iter()
                .map(|c| match c {
                    depthsense_prep::layout::Condition::Day => "day",
                    depthsense_prep::layout::Condition::Night => "night",
                    depthsense_prep::layout::Condition::Rain => "rain",
                })
                .collect();
            ev.add(&depthsense_metrics::EvalImage {
                pred_m: &pred_v[i * hw..(i + 1) * hw],
                gt_m: &s.sparse_m,
                lowheight: if s.lowheight.is_empty() {
                    None
                } else {
                    Some(&s.lowheight)
                },
                conditions: &conds,
            })?;
        }
        on_batch(&batch, &pred_v)?;
        progress.inc(batch.size as u64);
    }
    Ok(ev.finish())
}

fn all_finite(vs: &VarStore) -> bool {
    tch::no_grad(|| {
        vs.variables().values().all(|t| {
            if !t.is_floating_point() {
                return true;
            }
            t.isfinite().all().int64_value(&[]) == 1
        })
    })
}

fn append_jsonl(path: &Path, v: &serde_json::Value) -> Result<(), TrainError> {
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| TrainError::io(path, e))?;
    writeln!(f, "{v}").map_err(|e| TrainError::io(path, e))
}

/// Keep only the records of metrics.jsonl up to `iteration` (resume after an interruption).
fn truncate_metrics(path: &Path, iteration: u64) -> Result<(), TrainError> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(());
    };
    let kept: String = text
        .lines()
        .filter(|l| {
            serde_json::from_str::<serde_json::Value>(l)
                .ok()
                .and_then(|v| v.get("iteration").and_then(|i| i.as_u64()))
                .is_some_and(|i| i <= iteration)
        })
        .map(|l| format!("{l}\n"))
        .collect();
    write_atomic(path, kept.as_bytes()).map_err(|e| TrainError::io(path, e))
}

/// (global iteration, loss) pairs of a run.
pub type LossCurve = Vec<(u64, f64)>;

/// Read the loss curve and the validation records back from metrics.jsonl.
pub fn read_metrics(path: &Path) -> Result<(LossCurve, Vec<ValRecord>), TrainError> {
    let text = std::fs::read_to_string(path).map_err(|e| TrainError::io(path, e))?;
    let mut losses = vec![];
    let mut val = vec![];
    for l in text.lines() {
        let v: serde_json::Value = serde_json::from_str(l).map_err(|e| TrainError::Parse {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        match v.get("kind").and_then(|k| k.as_str()) {
            Some("iter") => losses.push((
                v["iteration"].as_u64().unwrap_or(0),
                v["loss"].as_f64().unwrap_or(f64::NAN),
            )),
            Some("epoch") | Some("val") => {
                if let Ok(r) = serde_json::from_value::<ValRecord>(v["val"].clone()) {
                    val.push(r);
                }
            }
            _ => {}
        }
    }
    Ok((losses, val))
}

fn save_ckpt(
    path: &Path,
    vs: &VarStore,
    cfg: &ModelConfig,
    state: &State,
    opts: &TrainOptions,
) -> Result<(), TrainError> {
    let extra = serde_json::json!({
        "train_state": state,
        "train_options": opts,
    });
    checkpoint::save(path, vs, cfg, &extra)?;
    Ok(())
}

/// Train a network. See the module docs for what lands in `opts.out`.
pub fn train(opts: &TrainOptions, progress: &ProgressBar) -> Result<TrainSummary, TrainError> {
    let started = Instant::now();
    if opts.batch_size == 0 || opts.epochs == 0 {
        return Err(TrainError::Config(
            "batch size and epochs must be at least 1".into(),
        ));
    }
    let device = depthsense_model::device::parse_device(&opts.device)?;
    let ds = Dataset::open(&opts.data)?;
    let part = partition(&ds, opts.val_every_scene)?;
    if part.train.is_empty() || part.val.is_empty() {
        return Err(TrainError::Data(format!(
            "{}: {} training and {} validation samples ({}): need both",
            opts.data.display(),
            part.train.len(),
            part.val.len(),
            part.method
        )));
    }
    let val_entries = subsample(&part.val, opts.max_val_samples);
    let run = opts.out.clone();
    std::fs::create_dir_all(&run).map_err(|e| TrainError::io(&run, e))?;
    let last = run.join(LAST_CKPT);
    let last_optim = run.join(LAST_OPTIM);
    let metrics_path = run.join(METRICS_FILE);

    // Frame size from the data: the model's output resolution follows it.
    let probe = crate::data::load_sample(
        &ds,
        &part.train[0],
        &LoadOptions {
            no_radar: true,
            ..LoadOptions::default()
        },
        &mut crate::data::Rng::new(0),
    )?;
    let mut cfg = opts.model.clone();
    cfg.out_height = probe.height as i64;
    cfg.out_width = probe.width as i64;

    // Network, optimiser and state: fresh or resumed.
    let (vs, net, mut state, mut sgd) = if opts.resume && last.exists() {
        // Build the requested network and copy the checkpoint into it: a checkpoint of another
        // configuration fails here with every offending tensor named (model::checkpoint).
        let vs = VarStore::new(device);
        let net = DepthNet::new(&vs.root(), &cfg)?;
        let bytes = std::fs::read(&last).map_err(|e| TrainError::io(&last, e))?;
        let (tensors, _) = checkpoint::parse_safetensors(&last, &bytes)?;
        checkpoint::copy_into(&last, &vs, &tensors)?;
        let (ck_cfg, extra) = checkpoint::read_config(&last)?;
        if ck_cfg != cfg {
            return Err(TrainError::Config(format!(
                "--resume: {} holds a different model config than requested \
                 (checkpoint preset {:?}, requested {:?}); resume with the same --config",
                last.display(),
                ck_cfg.name,
                cfg.name
            )));
        }
        let state: State = serde_json::from_value(extra["train_state"].clone()).map_err(|e| {
            TrainError::Parse {
                path: last.display().to_string(),
                reason: format!("train_state: {e}"),
            }
        })?;
        if state.batch_size != opts.batch_size
            || state.epochs != opts.epochs
            || state.lr != opts.lr
            || state.seed != opts.seed
        {
            return Err(TrainError::Config(format!(
                "--resume: {} was trained with batch {} epochs {} lr {} seed {}; \
                 an exact resume needs the same values (got batch {} epochs {} lr {} seed {})",
                last.display(),
                state.batch_size,
                state.epochs,
                state.lr,
                state.seed,
                opts.batch_size,
                opts.epochs,
                opts.lr,
                opts.seed
            )));
        }
        let mut sgd = Sgd::new(&vs, opts.momentum, opts.weight_decay);
        let opt_it = sgd.load(&last_optim)?;
        if opt_it != state.iteration {
            return Err(TrainError::Data(format!(
                "{} is at iteration {opt_it} but {} at {}: the pair is inconsistent",
                last_optim.display(),
                last.display(),
                state.iteration
            )));
        }
        truncate_metrics(&metrics_path, state.iteration)?;
        (vs, net, state, sgd)
    } else {
        if opts.resume {
            eprintln!(
                "note: --resume given but {} does not exist: starting from scratch",
                last.display()
            );
        }
        tch::manual_seed(opts.seed as i64);
        let mut vs = VarStore::new(device);
        let net = DepthNet::new(&vs.root(), &cfg)?;
        if let Some(w) = &opts.backbone_weights {
            let report = depthsense_model::weights::load_torchvision_resnet(&mut vs, w)?;
            eprintln!("backbone weights from {}: {report:?}", w.display());
        }
        let _ = std::fs::remove_file(&metrics_path);
        let sgd = Sgd::new(&vs, opts.momentum, opts.weight_decay);
        let state = State {
            kind: "depthsense-train".into(),
            iteration: 0,
            epoch: 0,
            seed: opts.seed,
            best_val_rmse: None,
            batch_size: opts.batch_size,
            epochs: opts.epochs,
            lr: opts.lr,
            val_rmse: None,
        };
        (vs, net, state, sgd)
    };

    let radar = radar_input_for(&cfg, opts.radar_input)?;
    let load = LoadOptions {
        radar: radar.unwrap_or_default(),
        target: opts.target,
        augment: opts.augment,
        eval_maps: false,
        no_radar: radar.is_none(),
        radar_drop: 0.0,
        seed: opts.seed,
    };
    let config_json = serde_json::json!({
        "train": opts,
        "model": cfg,
        "device": depthsense_model::device::describe(device),
        "partition": {
            "method": part.method,
            "train_samples": part.train.len(),
            "val_samples": part.val.len(),
            "val_samples_used": val_entries.len(),
            "val_scenes": part.val_scenes,
        },
    });
    write_atomic(
        &run.join(CONFIG_FILE),
        serde_json::to_string_pretty(&config_json)
            .map_err(|e| TrainError::Other(e.to_string()))?
            .as_bytes(),
    )
    .map_err(|e| TrainError::io(&run.join(CONFIG_FILE), e))?;

    let full_batches = part.train.len() / opts.batch_size;
    let drop_last = full_batches > 0;
    let natural = if drop_last { full_batches } else { 1 };
    let bpe = opts
        .max_batches_per_epoch
        .map_or(natural, |m| m.min(natural).max(1)) as u64;
    let total = bpe * opts.epochs as u64;
    progress.set_length(total);
    progress.set_position(state.iteration);

    let mut summary = TrainSummary {
        run_dir: run.clone(),
        losses: vec![],
        val: vec![],
        iterations_done: state.iteration,
        total_iterations: total,
        interrupted: false,
        best_val_rmse: state.best_val_rmse.unwrap_or(f64::INFINITY),
        train_images_per_s: 0.0,
        seconds: 0.0,
        partition: part.clone(),
    };
    let validate = |net: &DepthNet, epoch: u64, it: u64| -> Result<ValRecord, TrainError> {
        let r = evaluate_net(
            net,
            &ds,
            &val_entries,
            &load,
            &opts.eval,
            opts.batch_size,
            opts.jobs,
            device,
            &ProgressBar::hidden(),
            |_, _| Ok(()),
        )?;
        Ok(ValRecord::from_report(epoch, it, &r))
    };

    if state.iteration == 0 {
        progress.set_message("validating the initial network");
        let v = validate(&net, 0, 0)?;
        append_jsonl(
            &metrics_path,
            &serde_json::json!({"kind": "val", "epoch": 0, "iteration": 0, "val": v}),
        )?;
        summary.val.push(v);
    }

    let mut images = 0usize;
    let mut train_secs = 0.0f64;
    let start_epoch = state.iteration / bpe;
    for epoch in start_epoch..opts.epochs as u64 {
        let skip = (state.iteration - epoch * bpe) as usize;
        let plan = EpochPlan {
            entries: part.train.clone(),
            batch_size: opts.batch_size,
            epoch,
            shuffle: true,
            drop_last,
            skip_batches: skip,
            jobs: opts.jobs,
            prefetch: opts.prefetch,
        };
        let loader = Loader::start(&ds, &load, &plan)?;
        let mut epoch_loss = 0.0;
        let mut epoch_n = 0usize;
        let mut t_iter = Instant::now();
        for batch in loader.take((bpe as usize).saturating_sub(skip)) {
            let batch = batch?;
            let (image, radar_t, target) = batch_tensors(&batch, device);
            let it = state.iteration;
            let lr = poly_lr(opts.lr, it, total, opts.lr_power);
            // Dropout draws depend only on (seed, iteration): exact resume.
            tch::manual_seed((mix64(opts.seed ^ mix64(it + 1)) >> 1) as i64);
            let out = if opts.amp && device.is_cuda() {
                tch::autocast(true, || net.forward_t(&image, &radar_t, true))
            } else {
                net.forward_t(&image, &radar_t, true)
            };
            let loss = net.loss(&out.to_kind(Kind::Float), &target);
            let lv = loss.double_value(&[]);
            if !lv.is_finite() {
                return Err(TrainError::NonFiniteLoss {
                    loss: lv,
                    epoch,
                    iteration: it + 1,
                    kept: if last.exists() {
                        last.display().to_string()
                    } else {
                        "(none: no checkpoint had been written yet)".into()
                    },
                });
            }
            sgd.zero_grad();
            loss.backward();
            sgd.step(lr);
            state.iteration += 1;
            let dt = t_iter.elapsed().as_secs_f64();
            t_iter = Instant::now();
            train_secs += dt;
            images += batch.size;
            epoch_loss += lv;
            epoch_n += 1;
            summary.losses.push((state.iteration, lv));
            append_jsonl(
                &metrics_path,
                &serde_json::json!({"kind": "iter", "epoch": epoch, "iteration": state.iteration,
                                    "loss": lv, "lr": lr}),
            )?;
            progress.set_position(state.iteration);
            progress.set_message(format!(
                "epoch {}/{} loss {lv:.4} lr {lr:.2e} {:.1} img/s",
                epoch + 1,
                opts.epochs,
                batch.size as f64 / dt.max(1e-9)
            ));
            let epoch_end = state.iteration % bpe == 0;
            let stop_here = opts.stop_after == Some(state.iteration);
            if !epoch_end
                && (stop_here
                    || (opts.checkpoint_every > 0 && state.iteration % opts.checkpoint_every == 0))
            {
                state.epoch = epoch;
                checkpoint_pair(&vs, &cfg, &state, opts, &sgd, &last, &last_optim)?;
                if stop_here {
                    summary.interrupted = true;
                    return finish(
                        summary,
                        state,
                        images,
                        train_secs,
                        started,
                        &metrics_path,
                        &run,
                    );
                }
            }
        }

        // Epoch end: validate, checkpoint, log, plot.
        progress.set_message(format!("epoch {}/{}: validating", epoch + 1, opts.epochs));
        let v = validate(&net, epoch + 1, state.iteration)?;
        state.epoch = epoch + 1;
        state.val_rmse = Some(v.rmse);
        let improved = v.rmse < state.best_val_rmse.unwrap_or(f64::INFINITY);
        if improved {
            state.best_val_rmse = Some(v.rmse);
        }
        checkpoint_pair(&vs, &cfg, &state, opts, &sgd, &last, &last_optim)?;
        if improved {
            save_ckpt(&run.join(BEST_CKPT), &vs, &cfg, &state, opts)?;
        }
        append_jsonl(
            &metrics_path,
            &serde_json::json!({"kind": "epoch", "epoch": epoch + 1, "iteration": state.iteration,
                                "train_loss": epoch_loss / epoch_n.max(1) as f64,
                                "lr": poly_lr(opts.lr, state.iteration, total, opts.lr_power),
                                "images_per_s": images as f64 / train_secs.max(1e-9),
                                "seconds": started.elapsed().as_secs_f64(), "val": v}),
        )?;
        summary.val.push(v);
        write_curves(&metrics_path, &run.join(CURVES_FILE))?;
        if opts.stop_after == Some(state.iteration) {
            summary.interrupted = true;
            break;
        }
    }
    finish(
        summary,
        state,
        images,
        train_secs,
        started,
        &metrics_path,
        &run,
    )
}

fn checkpoint_pair(
    vs: &VarStore,
    cfg: &ModelConfig,
    state: &State,
    opts: &TrainOptions,
    sgd: &Sgd,
    last: &Path,
    last_optim: &Path,
) -> Result<(), TrainError> {
    if !all_finite(vs) {
        return Err(TrainError::NonFiniteLoss {
            loss: f64::NAN,
            epoch: state.epoch,
            iteration: state.iteration,
            kept: format!(
                "{} (weights became non-finite; not overwritten)",
                last.display()
            ),
        });
    }
    // Optimiser state first: a crash between the two leaves an optimiser file newer than the
    // checkpoint, which resume detects by the iteration numbers.
    sgd.save(last_optim, state.iteration)?;
    save_ckpt(last, vs, cfg, state, opts)
}

fn finish(
    mut summary: TrainSummary,
    state: State,
    images: usize,
    train_secs: f64,
    started: Instant,
    metrics_path: &Path,
    run: &Path,
) -> Result<TrainSummary, TrainError> {
    summary.iterations_done = state.iteration;
    summary.best_val_rmse = state.best_val_rmse.unwrap_or(f64::INFINITY);
    summary.train_images_per_s = images as f64 / train_secs.max(1e-9);
    summary.seconds = started.elapsed().as_secs_f64();
    if metrics_path.exists() {
        write_curves(metrics_path, &run.join(CURVES_FILE))?;
    }
    Ok(summary)
}

/// Render RUN/curves.png from RUN/metrics.jsonl.
pub fn write_curves(metrics_path: &Path, png: &Path) -> Result<(), TrainError> {
    let (losses, val) = read_metrics(metrics_path)?;
    let val_pts: Vec<(u64, f64)> = val.iter().map(|v| (v.iteration, v.rmse)).collect();
    let bytes = crate::plot::curves_png(&[("train loss", &losses)], &[("val RMSE (m)", &val_pts)])?;
    write_atomic(png, &bytes).map_err(|e| TrainError::io(png, e))
}
