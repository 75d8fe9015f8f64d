//! One training run as a [`Trainer`]: `new` (data, partition, network — fresh or resumed —
//! and RUN/config.json), `validate`, and the [`Learner`] that [`crate::learner::fit`] drives
//! step by step ([`train`], [`train_distributed`]): an epoch's batches from the prefetching
//! loader, the SGD step (its loss read every `loss_read_every` steps), checkpoints, epoch ends.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::step::{forward_loss, step_precision};
use depthsense_checkpoint as checkpoint;
use depthsense_config::refusal::{ConfigDifference, TrainingRefusal as Refusal};
use depthsense_config::ModelConfig;
use depthsense_config::RadarInput;
use depthsense_data::{Batch, EpochPlan, LoadOptions, Loader};
use depthsense_dataset::{partition, Dataset, Partition};
use depthsense_model::sync_bn::TrainHooks;
use depthsense_model::DepthNet;
use depthsense_prep::layout::IndexEntry;
use depthsense_progress::Progress;
use tch::{nn::VarStore, Device, Kind};

use super::{
    all_finite, save_ckpt, subsample, upload_batch, validate_net, write_curves, State,
    TrainOptions, TrainSummary, ValRecord,
};
use crate::distributed::Dist;
use crate::learner::{fit, Batches, Checkpointer, Clock, EpochTiming, Learner, Plan, StepDone};
use crate::metrics_log::{logged_loss_sum, EpochRecord, IterRecord};
use crate::optim::Optimizer;
use crate::optim_state;
use crate::run_folder::RunFolder;
use crate::schedule::{seed_step, warmup_poly_lr};
use crate::sgd::Sgd;
use depthsense_dataset::outputs::{
    BEST_CKPT, CONFIG_FILE, CURVES_FILE, LAST_CKPT, LAST_OPTIM, METRICS_FILE,
};
use depthsense_infer::NetError;
use depthsense_records::metrics_log::MetricsRecord;
use depthsense_records::run_config::{Command, LrSegment, TrainRunConfig, RUN_CONFIG_VERSION};
use depthsense_records::{convert, RecordError};

/// A training run in progress.
pub struct Trainer<'o> {
    opts: &'o TrainOptions,
    device: Device,
    ds: Dataset,
    part: Partition,
    val_entries: Vec<IndexEntry>,
    cfg: ModelConfig,
    vs: VarStore,
    net: DepthNet,
    state: State,
    optim: Sgd,
    load: LoadOptions,
    run: PathBuf,
    /// Batches per epoch and total iterations.
    bpe: u64,
    total: u64,
    /// When this invocation began (its set-up included in the records' wall seconds).
    started: Instant,
    /// The last loss read and its learning rate (the progress line).
    last_loss: Option<(f64, f64)>,
    /// Data-parallel training: this process's rank of the job (None: a single process).
    dist: Option<Dist>,
    /// The run folder, held by the process that writes it (rank 0 or the only one).
    folder: Option<RunFolder>,
    /// RUN/last.safetensors with its optimiser state.
    ckpt: Checkpointer,
    /// (iteration, loss) of every step of this invocation.
    losses: Vec<(u64, f64)>,
    /// The current epoch's losses (pending and read).
    acc: EpochLosses,
    /// Whether this invocation wrote RUN/best.safetensors.
    best_written: bool,
}

/// One optimiser step whose loss has not been read yet.
struct PendingLoss {
    /// Global iteration after the step.
    iteration: u64,
    /// The loss: a 0-d tensor on the training device (deferred read) or on the CPU (read).
    loss: tch::Tensor,
    lr: f64,
}

/// The losses of an epoch: those not read yet and the running sum of those read.
#[derive(Default)]
struct EpochLosses {
    pending: Vec<PendingLoss>,
    sum: f64,
    n: usize,
}

/// What opening a run came to: a trainer ready to run, or — `--resume` of a run that has
/// already done all its epochs — the summary of that finished run (an outcome, not an error:
/// nothing to do, nothing changed).
pub enum Opened<'o> {
    Ready(Box<Trainer<'o>>),
    Finished(Box<TrainSummary>),
}

impl Opened<'_> {
    /// Trains to the end (or to `stop_after`, or to a stop signal); a finished run's summary
    /// as it is.
    pub fn run(self, progress: &Progress) -> Result<TrainSummary, NetError> {
        match self {
            Opened::Ready(t) => t.run(progress),
            Opened::Finished(s) => Ok(*s),
        }
    }
}

impl<'o> Trainer<'o> {
    /// Opens the data, partitions it, builds (or resumes) the network and writes RUN/config.json.
    pub fn open(opts: &'o TrainOptions) -> Result<Opened<'o>, NetError> {
        Self::open_with_dist(opts, None)
    }

    /// [`Trainer::open`] for one rank of a data-parallel job (`None`: a single process);
    /// `opts.schedule.batch_size` is the global batch (see [`crate::distributed`]).
    pub fn open_with_dist(
        opts: &'o TrainOptions,
        mut dist: Option<Dist>,
    ) -> Result<Opened<'o>, NetError> {
        let started = Instant::now();
        let main = check_options(opts, dist.as_ref())?;
        let folder = main.then(|| take_run_folder(opts)).transpose()?;
        let device = depthsense_model::device::parse_device(&opts.hardware.device.name)?;
        depthsense_model::device::autotune_fixed_size(device);
        let (ds, part) = open_partition(opts)?;
        let val_entries = subsample(&part.val, opts.validation.max_val_samples);
        let run = opts.out.clone();
        let cfg = model_config_for_data(opts, &ds)?;
        let bpe = opts.schedule.iterations_per_epoch(part.train.len());
        if let Some(state) = finished_state(opts, &cfg, bpe)? {
            let n_val = val_entries.len();
            let summary = finished_summary(opts, &state, part, n_val, bpe, started);
            return Ok(Opened::Finished(Box::new(summary)));
        }
        // Data parallelism is decided when the network is built (SyncBatchNorm, dropout seeds).
        let hooks = dist.as_mut().map(Dist::train_hooks).unwrap_or_default();
        let ((vs, net, mut state, optim), optim_matches) =
            network(opts, &cfg, device, main, bpe, &hooks)?;
        if let Some(f) = &folder {
            f.restart_log(state.iteration)?;
        }
        if state.data_settings.is_empty() {
            state.data_settings = ds.index.settings.clone();
        }
        if let Some(d) = dist.as_mut() {
            attach(d, &vs, part.train.len(), opts.schedule.batch_size)?;
        }
        let load = train_load_options(opts, &cfg)?;
        let trainer = Trainer {
            opts,
            device,
            ds,
            part,
            val_entries,
            cfg,
            vs,
            net,
            state,
            optim,
            load,
            run: run.clone(),
            bpe,
            total: plan_of(opts, bpe).total_iterations(),
            started,
            last_loss: None,
            dist,
            folder,
            ckpt: Checkpointer::new(&run, optim_matches),
            losses: vec![],
            acc: EpochLosses::default(),
            best_written: false,
        };
        if main {
            trainer.write_config()?;
        }
        Ok(Opened::Ready(Box::new(trainer)))
    }

    /// Rank 0 of a job, or a single process: the one that writes RUN/.
    fn is_main(&self) -> bool {
        self.dist.as_ref().is_none_or(|d| d.is_main())
    }

    /// Communication statistics of this rank (None for a single process).
    pub fn comm_stats(&self) -> Option<crate::distributed::CommStats> {
        self.dist.as_ref().map(|d| d.stats)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.run.join(name)
    }

    fn write_config(&self) -> Result<(), NetError> {
        let part = &self.part;
        let path = self.path(CONFIG_FILE);
        let record = |e: RecordError| NetError::Parse {
            path: e.path.clone(),
            reason: e.reason(),
        };
        let config = TrainRunConfig {
            format_version: RUN_CONFIG_VERSION,
            train: convert(self.opts, &path).map_err(record)?,
            model: convert(&self.cfg, &path).map_err(record)?,
            device: Some(depthsense_model::device::describe(self.device)),
            partition: convert(
                &serde_json::json!({
                    "method": part.method,
                    "train_samples": part.train.len(),
                    "val_samples": part.val.len(),
                    "val_samples_used": self.val_entries.len(),
                    "val_scenes": part.val_scenes,
                }),
                &path,
            )
            .map_err(record)?,
            // An extended run (`--extend`): every learning-rate segment, the last one current.
            schedule: self
                .state
                .schedule
                .iter()
                .map(|s| LrSegment {
                    start_iteration: s.start_iteration,
                    end_iteration: s.end_iteration,
                    lr: s.lr,
                    warmup: s.warmup,
                })
                .collect(),
            init_from: match &self.state.init_from {
                Some(init) => Some(convert(init, &path).map_err(record)?),
                None => None,
            },
            command: Command::of_words(&self.opts.command),
        };
        match &self.folder {
            Some(folder) => folder.write_config(&config),
            None => Ok(()),
        }
    }

    /// Metrics of the current network on the validation samples.
    pub fn validate(&self, epoch: u64) -> Result<ValRecord, NetError> {
        let shard = match &self.dist {
            Some(d) => &self.val_entries[d.shard(self.val_entries.len())],
            None => &self.val_entries[..],
        };
        let r = validate_net(
            &self.net,
            &self.ds,
            shard,
            &self.load,
            &self.opts.eval,
            self.opts.schedule.batch_size,
            self.opts.loading.jobs,
            self.device,
            &Progress::hidden(),
        )?;
        let r = match &self.dist {
            Some(d) => d.reduce_report(&r)?,
            None => r,
        };
        Ok(ValRecord::from_report(epoch, self.state.iteration, &r))
    }

    /// Iterations between two reads of the losses (see [`TrainOptions::loss_read_every`]).
    fn loss_read_every(&self) -> usize {
        match self.opts.hardware.loss_read_every {
            _ if self.dist.is_some() => 1,
            0 if self.device.is_cuda() => super::CUDA_LOSS_READ_EVERY as usize,
            0 => 1,
            n => n as usize,
        }
    }

    /// The error for a non-finite loss at `iteration` (nothing is overwritten).
    fn non_finite(&self, loss: f64, epoch: u64, iteration: u64) -> NetError {
        let last = self.path(LAST_CKPT);
        NetError::NonFiniteLoss {
            loss,
            epoch,
            iteration,
            kept: if last.exists() {
                last.display().to_string()
            } else {
                "(none: no checkpoint had been written yet)".into()
            },
        }
    }

    /// The learning rate of iteration `it`: poly decay (SPEC §8) after the optional warmup.
    fn lr_at(&self, it: u64) -> f64 {
        let o = self.opts;
        match self
            .state
            .schedule
            .iter()
            .rev()
            .find(|s| s.start_iteration <= it)
        {
            None => warmup_poly_lr(
                o.schedule.lr,
                it,
                self.total,
                o.schedule.lr_power,
                o.schedule.warmup_iters,
            ),
            Some(s) => warmup_poly_lr(
                s.lr,
                it - s.start_iteration,
                s.end_iteration - s.start_iteration,
                o.schedule.lr_power,
                s.warmup,
            ),
        }
    }

    /// One SGD step on `batch`. Its loss stays on the device unless losses are read every
    /// iteration: then it is read here and a non-finite one stops before the update.
    fn sgd_step(&mut self, batch: &Batch, epoch: u64) -> Result<PendingLoss, NetError> {
        let opts = self.opts;
        let bt = upload_batch(batch, self.device);
        let it = self.state.iteration;
        let lr = self.lr_at(it);
        // Dropout draws depend only on (seed, iteration): exact resume.
        seed_step(opts.schedule.seed, it);
        let precision = step_precision(opts.hardware.amp);
        if let Some(d) = &self.dist {
            d.before_forward(opts.schedule.seed, it, batch.size)?;
        }
        let loss = forward_loss(&self.net, &bt, precision);
        let value = if self.loss_read_every() == 1 {
            let mut lv = loss.double_value(&[]);
            if let Some(d) = &self.dist {
                d.after_forward()?;
                lv = d.mean_loss(lv)?;
            }
            if !lv.is_finite() {
                return Err(self.non_finite(lv, epoch, it + 1));
            }
            tch::Tensor::from(lv)
        } else {
            loss.detach()
        };
        match self.dist.as_mut() {
            None => crate::step::backward_update(&mut self.optim, &loss, lr),
            Some(d) => {
                self.optim.zero_grad();
                loss.f_backward()?;
                d.sync_grads()?;
                self.optim.step(lr);
            }
        }
        self.state.iteration += 1;
        if let Some(d) = &self.dist {
            d.check_replicas(self.state.iteration)?;
        }
        Ok(PendingLoss {
            iteration: self.state.iteration,
            loss: value,
            lr,
        })
    }

    /// Reads the pending losses (one device→host copy) and logs them in order; the first
    /// non-finite one stops training with its own iteration.
    fn read_losses(&mut self, epoch: u64) -> Result<(), NetError> {
        if self.acc.pending.is_empty() {
            return Ok(());
        }
        let pending = std::mem::take(&mut self.acc.pending);
        let stacked: Vec<&tch::Tensor> = pending.iter().map(|p| &p.loss).collect();
        let values = tch::Tensor::stack(&stacked, 0)
            .to_kind(Kind::Double)
            .to_device(Device::Cpu);
        let values = Vec::<f64>::try_from(&values)?;
        for (p, lv) in pending.iter().zip(values) {
            if !lv.is_finite() {
                return Err(self.non_finite(lv, epoch, p.iteration));
            }
            self.acc.sum += lv;
            self.acc.n += 1;
            self.losses.push((p.iteration, lv));
            if let Some(f) = &self.folder {
                f.append::<ValRecord>(&MetricsRecord::Iter(IterRecord::new(
                    epoch,
                    p.iteration,
                    lv,
                    p.lr,
                )))?;
            }
            self.last_loss = Some((lv, p.lr));
        }
        Ok(())
    }

    /// Writes RUN/last.safetensors and its optimiser state (refusing non-finite weights).
    fn checkpoint(&mut self) -> Result<(), NetError> {
        let last = self.path(LAST_CKPT);
        let state = &self.state;
        if !all_finite(&self.vs) {
            return Err(NetError::NonFiniteLoss {
                loss: f64::NAN,
                epoch: state.epoch,
                iteration: state.iteration,
                kept: format!(
                    "{} (weights became non-finite; not overwritten)",
                    last.display()
                ),
            });
        }
        if !self.is_main() {
            return Ok(());
        }
        // Optimiser state first, the previous one kept until the checkpoint is written.
        self.ckpt.save_last(
            |optim| self.optim.save(optim, state.iteration),
            |last| save_ckpt(last, &self.vs, &self.cfg, state, self.opts),
        )
    }

    /// Epoch `epoch`'s (0-based) record in RUN/metrics.jsonl, validated as `v`, and the curves.
    fn write_epoch_record(
        &mut self,
        epoch: u64,
        v: &ValRecord,
        timing: &EpochTiming,
    ) -> Result<(), NetError> {
        let (epoch_loss, epoch_n) = (self.acc.sum, self.acc.n);
        let Some(folder) = &self.folder else {
            return Ok(());
        };
        let it = self.state.iteration;
        folder.append(&MetricsRecord::Epoch(timing.stamp(EpochRecord {
            lr: Some(self.lr_at(it)),
            ..EpochRecord::new(epoch + 1, it, epoch_loss / epoch_n.max(1) as f64, v.clone())
        })))?;
        write_curves(&self.path(METRICS_FILE), &self.path(CURVES_FILE))
    }

    /// What RUN/best.safetensors holds now.
    fn best(&self) -> super::BestCheckpoint {
        super::BestCheckpoint {
            val_rmse: self.state.best_val_rmse,
            iteration: self.state.best_iteration,
            epoch: self.state.best_epoch,
            written_by_this_run: self.best_written,
        }
    }

    /// The loader of epoch `epoch` from its batch `skip` on; the epoch's running loss starts
    /// with the losses of the iterations before a resume (read back from metrics.jsonl), as in
    /// an uninterrupted run.
    fn epoch_loader(&mut self, epoch: u64, skip: u64) -> Result<Loader, NetError> {
        let opts = self.opts;
        // An epoch of `epoch_iterations` draws its samples from the stream of passes itself.
        let (entries, shuffle) = match opts.schedule.epoch_iterations {
            Some(block) => (
                block_entries(
                    &self.part.train,
                    opts.schedule.seed,
                    epoch,
                    block,
                    opts.schedule.batch_size,
                ),
                false,
            ),
            None => (self.part.train.clone(), true),
        };
        let plan = EpochPlan {
            drop_last: entries.len() / opts.schedule.batch_size > 0,
            entries,
            batch_size: opts.schedule.batch_size,
            epoch,
            shuffle,
            skip_batches: skip as usize,
            jobs: opts.loading.jobs,
            prefetch: opts.loading.prefetch,
        };
        let (rank, world) = self.rank_world();
        let loader = Loader::start_shard(&self.ds, &self.load, &plan, rank, world)?;
        self.acc = EpochLosses::default();
        if skip > 0 && self.is_main() {
            let path = self.path(METRICS_FILE);
            (self.acc.sum, self.acc.n) =
                logged_loss_sum(&path, epoch * self.bpe, self.state.iteration);
        }
        Ok(loader)
    }

    /// (rank, world size) of this process (0, 1 alone).
    fn rank_world(&self) -> (usize, usize) {
        self.dist
            .as_ref()
            .map_or((0, 1), |d| (d.rank(), d.world_size()))
    }

    /// Trains to the end (or to `stop_after`).
    pub fn run(mut self, progress: &Progress) -> Result<TrainSummary, NetError> {
        progress.println(self.start_line());
        let fitted = fit(&mut self, progress)?;
        let clock = fitted.clock;
        let summary = TrainSummary {
            run_dir: self.run.clone(),
            losses: std::mem::take(&mut self.losses),
            val: fitted.val,
            iterations_done: self.state.iteration,
            total_iterations: self.total,
            interrupted: fitted.interrupted,
            signal: fitted.signal,
            already_finished: None,
            best_val_rmse: self.state.best_val_rmse.unwrap_or(f64::INFINITY),
            best: self.best(),
            train_images_per_s: 0.0,
            train_seconds: 0.0,
            val_seconds: 0.0,
            seconds: 0.0,
            partition: self.part.clone(),
            val_samples_used: self.val_entries.len(),
        };
        self.finish(summary, &clock)
    }

    /// What the run trains on and for how long (the first line of its log).
    fn start_line(&self) -> String {
        let o = self.opts;
        let from = match self.state.iteration {
            0 => String::new(),
            it => format!(", resumed at iteration {it}"),
        };
        let params = depthsense_model::pda::parameter_count(&self.vs) as f64 / 1e6;
        format!(
            "{} ({}, {params:.2} M parameters) on {} training / {} validation samples of {}; {} \
             epochs × {} iterations = {} iterations, batch {}, lr {}, {}{from} → {}",
            self.cfg.name,
            fusion_words(&self.cfg),
            self.part.train.len(),
            self.val_entries.len(),
            o.data.display(),
            o.schedule.epochs,
            self.bpe,
            self.total,
            o.schedule.batch_size,
            o.schedule.lr,
            depthsense_model::device::describe(self.device),
            self.run.display()
        )
    }

    fn finish(self, mut summary: TrainSummary, clock: &Clock) -> Result<TrainSummary, NetError> {
        summary.iterations_done = self.state.iteration;
        summary.best_val_rmse = self.state.best_val_rmse.unwrap_or(f64::INFINITY);
        summary.best = self.best();
        summary.train_images_per_s = clock.images_per_s();
        summary.train_seconds = clock.train_secs;
        summary.val_seconds = clock.val_secs;
        summary.seconds = clock.seconds();
        let metrics = self.path(METRICS_FILE);
        if self.is_main() && metrics.exists() {
            write_curves(&metrics, &self.path(CURVES_FILE))?;
        }
        if let Some(d) = &self.dist {
            if d.is_main() {
                eprintln!("{}", comm_line(d));
            }
            d.barrier()?;
        }
        Ok(summary)
    }
}

impl Learner for Trainer<'_> {
    type Val = ValRecord;
    type Batch = Batch;

    fn iteration(&self) -> u64 {
        self.state.iteration
    }

    fn started(&self) -> Instant {
        self.started
    }

    fn plan(&self) -> Plan {
        plan_of(self.opts, self.bpe)
    }

    fn validation(&mut self, epoch: u64) -> Result<ValRecord, NetError> {
        let v = self.validate(epoch)?;
        if epoch > 0 {
            self.state.epoch = epoch;
            self.state.val_rmse = Some(v.rmse);
        }
        Ok(v)
    }

    fn score(v: &ValRecord) -> f64 {
        v.rmse
    }

    fn best_score(&self) -> Option<f64> {
        self.state.best_val_rmse
    }

    fn note_best(&mut self, v: &ValRecord) {
        self.state.best_val_rmse = Some(v.rmse);
        self.state.best_iteration = Some(self.state.iteration);
        self.state.best_epoch = Some(self.state.epoch);
        self.best_written = true;
    }

    fn save_best(&mut self) -> Result<(), NetError> {
        if !self.is_main() {
            return Ok(());
        }
        save_ckpt(
            &self.path(BEST_CKPT),
            &self.vs,
            &self.cfg,
            &self.state,
            self.opts,
        )
    }

    fn run_folder(&self) -> Option<&RunFolder> {
        self.folder.as_ref()
    }

    fn batches(&mut self, epoch: u64, skip: u64) -> Result<Batches<Batch>, NetError> {
        let loader = self.epoch_loader(epoch, skip)?;
        let left = self.bpe.saturating_sub(skip) as usize;
        Ok(Box::new(
            loader.take(left).map(|b| b.map_err(NetError::from)),
        ))
    }

    fn step(&mut self, batch: Batch, epoch: u64, _: &Progress) -> Result<StepDone, NetError> {
        let p = self.sgd_step(&batch, epoch)?;
        let iteration = p.iteration;
        self.acc.pending.push(p);
        if self.acc.pending.len() >= self.loss_read_every() {
            self.read_losses(epoch)?;
        }
        Ok(StepDone {
            iteration,
            images: (batch.size * self.rank_world().1) as u64,
        })
    }

    fn status(&self) -> String {
        crate::learner::loss_status(self.last_loss)
    }

    fn flush(&mut self, epoch: u64, _: &Progress) -> Result<(), NetError> {
        self.read_losses(epoch)
    }

    fn save_last(&mut self, epoch: u64) -> Result<(), NetError> {
        self.state.epoch = epoch;
        self.checkpoint()
    }

    fn log_epoch(
        &mut self,
        epoch: u64,
        v: &ValRecord,
        timing: &EpochTiming,
    ) -> Result<(), NetError> {
        self.write_epoch_record(epoch, v, timing)
    }

    fn dist(&self) -> Option<&Dist> {
        self.dist.as_ref()
    }
}

/// The gradient all-reduce of this invocation on rank 0, one line (gpu-check reads it): bytes and
/// buckets per step, the mean time per step and the algorithm bandwidth (bytes / time).
fn comm_line(d: &Dist) -> String {
    let s = d.stats;
    let per_step = s.grad_allreduce_s / s.steps.max(1) as f64;
    format!(
        "all-reduce ({}, {} ranks): {:.1} MB of gradients per step in {} buckets, {} steps, \
         {:.3} ms per step, {:.2} GB/s algorithm bandwidth",
        d.process_group().backend_name(),
        d.world_size(),
        s.grad_bytes as f64 / 1e6,
        s.buckets,
        s.steps,
        per_step * 1e3,
        s.grad_bytes as f64 / per_step.max(1e-12) / 1e9
    )
}

/// The run's length and cadence: the one place iterations × epochs is worked out.
fn plan_of(opts: &TrainOptions, iterations_per_epoch: u64) -> Plan {
    Plan {
        iterations_per_epoch,
        epochs: opts.schedule.epochs as u64,
        checkpoint_every: opts.checkpointing.checkpoint_every,
        stop_after: opts.checkpointing.stop_after,
    }
}

/// `--resume` (not `--extend`) of a run whose checkpoint has done all its iterations: that
/// checkpoint's training state, read from its header alone (no network is built, no tensor
/// read). None otherwise — also for a checkpoint of another config or schedule: [`resume`]
/// refuses it then, with every tensor of another shape named when the copy fails first.
fn finished_state(
    opts: &TrainOptions,
    cfg: &ModelConfig,
    bpe: u64,
) -> Result<Option<State>, NetError> {
    let last = opts.out.join(LAST_CKPT);
    if !opts.checkpointing.resume || opts.extension.extend || !last.exists() {
        return Ok(None);
    }
    let (ck_cfg, extra) = checkpoint::read_config(&last)?;
    let state = train_state(&last, &extra)?;
    let done = state.iteration >= plan_of(opts, bpe).total_iterations();
    let same = &ck_cfg == cfg && state.schedule_key() == opts.schedule.key();
    Ok((done && same).then_some(state))
}

/// The training state stored in a checkpoint's extra JSON (`"train_state"`).
fn train_state(last: &Path, extra: &serde_json::Value) -> Result<State, NetError> {
    serde_json::from_value(extra["train_state"].clone()).map_err(|e| NetError::Parse {
        path: last.to_path_buf(),
        reason: format!("train_state: {e}"),
    })
}

/// The summary of a run that `--resume` found finished: nothing trained, nothing written.
fn finished_summary(
    opts: &TrainOptions,
    state: &State,
    partition: Partition,
    val_samples_used: usize,
    bpe: u64,
    started: Instant,
) -> TrainSummary {
    TrainSummary {
        run_dir: opts.out.clone(),
        losses: vec![],
        val: vec![],
        iterations_done: state.iteration,
        total_iterations: plan_of(opts, bpe).total_iterations(),
        interrupted: false,
        signal: None,
        best_val_rmse: state.best_val_rmse.unwrap_or(f64::INFINITY),
        best: super::BestCheckpoint {
            val_rmse: state.best_val_rmse,
            iteration: state.best_iteration,
            epoch: state.best_epoch,
            written_by_this_run: false,
        },
        train_images_per_s: 0.0,
        train_seconds: 0.0,
        val_seconds: 0.0,
        seconds: started.elapsed().as_secs_f64(),
        partition,
        val_samples_used,
        already_finished: Some(super::FinishedRun {
            run: opts.out.clone(),
            epochs: opts.schedule.epochs,
            iteration: state.iteration,
        }),
    }
}

/// Takes the run folder for this process (rank 0, or the only one): one writer per run folder,
/// and a finished run is never replaced silently (crate::outputs): refused unless --resume,
/// --extend or --force.
fn take_run_folder(opts: &TrainOptions) -> Result<RunFolder, NetError> {
    let c = &opts.checkpointing;
    RunFolder::take(
        &opts.out,
        "train",
        c.resume || opts.extension.extend,
        c.force,
    )
}

/// The options every rank checks before touching the run folder; returns whether this is the
/// main process (rank 0, or a single process).
fn check_options(opts: &TrainOptions, dist: Option<&Dist>) -> Result<bool, NetError> {
    let (main, world) = dist.map_or((true, 1), |d| (d.is_main(), d.world_size()));
    opts.schedule.check(world)?;
    opts.loading.check()?;
    Ok(main)
}

/// The prepared data and its partition, training scenes withheld (`--exclude`); both the
/// training and the validation partition must hold samples.
fn open_partition(opts: &TrainOptions) -> Result<(Dataset, Partition), NetError> {
    let ds = Dataset::open(&opts.data)?;
    let mut part = partition(&ds, opts.validation.val_every_scene)?;
    depthsense_data::exclusion::apply_exclusions(&mut part, &opts.exclude);
    if let Some(n) = opts.loading.train_subset {
        if n > part.train.len() {
            return Err(Refusal::SubsetTooLarge {
                requested: n,
                data: opts.data.clone(),
                available: part.train.len(),
            }
            .into());
        }
        part.train = training_subset(&part.train, n);
    }
    part.require_train_and_val(&opts.data)?;
    Ok((ds, part))
}

/// The first `n` of `train` in a fixed order (SplitMix64 of each sample token's FNV-1a hash):
/// nested for growing `n`, the same for every seed and variant; returned in `train`'s order.
pub fn training_subset(train: &[IndexEntry], n: usize) -> Vec<IndexEntry> {
    let key = |e: &IndexEntry| {
        depthsense_base::hash::splitmix64(depthsense_base::hash::fnv1a64(e.sample_token.as_bytes()))
    };
    let mut order: Vec<usize> = (0..train.len()).collect();
    order.sort_by_key(|&i| (key(&train[i]), i));
    let mut keep: Vec<usize> = order.into_iter().take(n).collect();
    keep.sort_unstable();
    keep.into_iter().map(|i| train[i].clone()).collect()
}

/// The training samples of epoch `epoch` when epochs are `block` iterations of `batch` samples
/// (`epoch_iterations`): positions `epoch·block·batch ..` of the stream of passes over
/// `train`, each pass in the loader's shuffled order of that pass.
fn block_entries(
    train: &[IndexEntry],
    seed: u64,
    epoch: u64,
    block: u64,
    batch: usize,
) -> Vec<IndexEntry> {
    let n = train.len().max(1);
    let len = block as usize * batch;
    let start = epoch as usize * len;
    let mut out = Vec::with_capacity(len);
    let mut pass = usize::MAX;
    let mut order = vec![];
    for s in start..start + len {
        if s / n != pass {
            pass = s / n;
            order = depthsense_data::epoch_order(n, seed, pass as u64, true);
        }
        out.push(train[order[s % n]].clone());
    }
    out
}

/// What the training loader reads and how (SPEC §8 augmentation, `--train-radar-drop`).
fn train_load_options(opts: &TrainOptions, cfg: &ModelConfig) -> Result<LoadOptions, NetError> {
    let radar = cfg.radar_input_for(opts.radar_input)?;
    Ok(LoadOptions {
        radar: radar.unwrap_or_default(),
        target: opts.loading.target,
        augment: opts.loading.augment,
        eval_maps: false,
        no_radar: radar.is_none(),
        radar_drop: 0.0,
        seed: opts.schedule.seed,
        failure: Default::default(),
        train_radar_drop: opts.loading.train_radar_drop,
        radar_oracle: opts.loading.radar_oracle,
    })
}

/// `late fusion + attention`, `late fusion`, `early fusion` or `RGB only`.
fn fusion_words(cfg: &ModelConfig) -> &'static str {
    match (cfg.fusion, cfg.attention) {
        (depthsense_config::Fusion::Late, true) => "late fusion + attention",
        (depthsense_config::Fusion::Late, false) => "late fusion",
        (depthsense_config::Fusion::Early, _) => "early fusion",
        (depthsense_config::Fusion::None, _) => "RGB only",
    }
}

/// The requested model config with the output resolution of the data's frames.
fn model_config_for_data(opts: &TrainOptions, ds: &Dataset) -> Result<ModelConfig, NetError> {
    let (width, height) = ds.frame_size()?;
    let mut cfg = opts.model.clone();
    cfg.out_height = height.into();
    cfg.out_width = width.into();
    // The radar input is part of the model (SPEC §5): `--radar-input` when given, else the
    // config's, adjusted to a 2-channel config.
    cfg.radar_input = match opts.radar_input {
        Some(r) => r,
        None if cfg.radar_input.channels() as i64 == cfg.radar_channels => cfg.radar_input,
        None => RadarInput::for_channels(cfg.radar_channels)?,
    };
    Ok(cfg)
}

/// The network, its state and optimiser: RUN/last.safetensors continued (`--resume`,
/// `--extend`), or a fresh one; and whether the optimiser state on disk matched.
fn network(
    opts: &TrainOptions,
    cfg: &ModelConfig,
    device: Device,
    main: bool,
    bpe: u64,
    hooks: &TrainHooks,
) -> Result<(Built, bool), NetError> {
    let run = &opts.out;
    if (opts.checkpointing.resume || opts.extension.extend) && run.join(LAST_CKPT).exists() {
        return resume(opts, run, cfg, device, bpe, hooks);
    }
    if opts.extension.extend {
        return Err(Refusal::NothingToExtend {
            run: run.clone(),
            checkpoint: LAST_CKPT,
        }
        .into());
    }
    Ok((fresh(opts, run, cfg, device, main, hooks)?, true))
}

/// This rank's network joins the job (its parameters broadcast from rank 0), once the global
/// batch is known to fit the training samples.
fn attach(d: &mut Dist, vs: &VarStore, train_samples: usize, batch: usize) -> Result<(), NetError> {
    if train_samples < batch {
        return Err(Refusal::FewerSamplesThanBatch {
            samples: train_samples,
            batch,
        }
        .into());
    }
    d.attach(vs)
}

type Built = (VarStore, DepthNet, State, Sgd);

/// A new network (seeded), optional ImageNet backbone, empty optimiser state.
fn fresh(
    opts: &TrainOptions,
    run: &Path,
    cfg: &ModelConfig,
    device: Device,
    main: bool,
    hooks: &TrainHooks,
) -> Result<Built, NetError> {
    let last = run.join(LAST_CKPT);
    if opts.checkpointing.resume && main {
        eprintln!(
            "note: --resume given but {} does not exist: starting from scratch",
            last.display()
        );
    }
    tch::manual_seed(opts.schedule.seed as i64);
    let mut vs = VarStore::new(device);
    let net = DepthNet::with_hooks(&vs.root(), cfg, hooks)?;
    if let Some(w) = &opts.backbone_weights {
        let report = depthsense_checkpoint::weights::load_torchvision_resnet(&mut vs, w)?;
        eprintln!("backbone weights from {}:\n{report}", w.display());
    }
    let init_from = match &opts.init_from {
        Some(p) => Some(init_from(&mut vs, p, main)?),
        None => None,
    };
    let optim = Sgd::new(&vs, opts.schedule.momentum, opts.schedule.weight_decay);
    let state = State {
        kind: "depthsense-train".into(),
        iteration: 0,
        epoch: 0,
        seed: opts.schedule.seed,
        best_val_rmse: None,
        best_iteration: None,
        best_epoch: None,
        batch_size: opts.schedule.batch_size,
        epochs: opts.schedule.epochs,
        lr: opts.schedule.lr,
        val_rmse: None,
        schedule: vec![],
        init_from,
        data_settings: Default::default(),
    };
    Ok((vs, net, state, optim))
}

/// `--init-from`: the fresh network in `vs` starts from the weights of `file`; what was
/// loaded is said (by the main process) and returned as config.json's `"init_from"`.
fn init_from(vs: &mut VarStore, file: &Path, main: bool) -> Result<serde_json::Value, NetError> {
    let r = depthsense_checkpoint::weights::init_from(vs, file)?;
    if main {
        eprintln!(
            "initialised from {} (tensors it lacks are new, \"left random\"):\n{r}",
            file.display()
        );
    }
    Ok(serde_json::json!({
        "file": file.display().to_string(),
        "loaded": r.loaded.len(),
        "partly_loaded": r.partial.iter().map(|(k, _)| k).collect::<Vec<_>>(),
        "new": r.left_random,
        "unused_file_tensors": r.unused.len() + r.skipped.len(),
    }))
}

/// The network, state and optimiser of RUN/last.safetensors, checked against `opts`; and
/// whether RUN/last.optim.safetensors itself held the optimiser state (see
/// [`optim_state::load_matching`]).
fn resume(
    opts: &TrainOptions,
    run: &Path,
    cfg: &ModelConfig,
    device: Device,
    bpe: u64,
    hooks: &TrainHooks,
) -> Result<(Built, bool), NetError> {
    let last = run.join(LAST_CKPT);
    let last_optim = run.join(LAST_OPTIM);
    // Build the requested network and copy the checkpoint into it: a checkpoint of another
    // configuration fails here with every offending tensor named (depthsense_checkpoint).
    let vs = VarStore::new(device);
    let net = DepthNet::with_hooks(&vs.root(), cfg, hooks)?;
    let bytes = std::fs::read(&last).map_err(|e| NetError::io(&last, e))?;
    let (tensors, meta) = depthsense_checkpoint::host::parse_safetensors(&last, &bytes)?;
    checkpoint::copy_into(&last, &vs, &tensors)?;
    let (ck_cfg, extra) = checkpoint::config_of(&last, &meta)?;
    if &ck_cfg != cfg {
        return Err(Refusal::OtherModel {
            checkpoint: last,
            differences: ConfigDifference::between(&ck_cfg, cfg),
            stored: ck_cfg.name,
            requested: cfg.name.clone(),
        }
        .into());
    }
    let mut state = train_state(&last, &extra)?;
    if opts.extension.extend {
        extend_schedule(opts, &last, &mut state, bpe)?;
    }
    check_same_schedule(&state, opts, &last)?;
    let mut optim = Sgd::new(&vs, opts.schedule.momentum, opts.schedule.weight_decay);
    let matches =
        optim_state::load_matching(&last_optim, &last, state.iteration, |p| optim.load(p))?;
    Ok(((vs, net, state, optim), matches))
}

/// An exact resume continues the same computation: the checkpoint's batch size, epochs,
/// learning rate and seed must be the options' (`--extend` has updated epochs and lr first).
fn check_same_schedule(state: &State, opts: &TrainOptions, last: &Path) -> Result<(), Refusal> {
    let (stored, requested) = (state.schedule_key(), opts.schedule.key());
    if stored != requested {
        return Err(Refusal::OtherSchedule {
            checkpoint: last.to_path_buf(),
            stored,
            requested,
        });
    }
    Ok(())
}

/// `--extend`: a new learning-rate segment from the checkpoint's iteration to the end of
/// `opts.schedule.epochs` (poly decay from `opts.schedule.lr` to 0); the run's first segment is written out when
/// this is its first extension. Batch size and seed must stay.
fn extend_schedule(
    opts: &TrainOptions,
    last: &Path,
    state: &mut State,
    bpe: u64,
) -> Result<(), NetError> {
    if opts.schedule.epochs <= state.epochs {
        return Err(Refusal::ExtendWithoutMoreEpochs {
            checkpoint: last.to_path_buf(),
            epochs: state.epochs,
        }
        .into());
    }
    let (stored, requested) = (state.schedule_key(), opts.schedule.key());
    if (stored.batch_size, stored.seed) != (requested.batch_size, requested.seed) {
        return Err(Refusal::ExtendChangesBatchOrSeed {
            checkpoint: last.to_path_buf(),
            stored,
            requested,
        }
        .into());
    }
    if state.schedule.is_empty() {
        state.schedule.push(super::Segment {
            start_iteration: 0,
            end_iteration: bpe * state.epochs as u64,
            lr: state.lr,
            warmup: opts.schedule.warmup_iters,
        });
    }
    state.schedule.push(super::Segment {
        start_iteration: state.iteration,
        end_iteration: bpe * opts.schedule.epochs as u64,
        lr: opts.schedule.lr,
        warmup: 0,
    });
    state.epochs = opts.schedule.epochs;
    state.lr = opts.schedule.lr;
    Ok(())
}

/// Train a network. See the module docs for what lands in `opts.out`.
pub fn train(opts: &TrainOptions, progress: &Progress) -> Result<TrainSummary, NetError> {
    removing_new_folder_on_failure(&opts.out, || Trainer::open(opts)?.run(progress))
}

/// [`train`] as one rank of a data-parallel job (only rank 0 writes RUN/; pass a hidden
/// progress bar on the other ranks).
pub fn train_distributed(
    opts: &TrainOptions,
    dist: Dist,
    progress: &Progress,
) -> Result<TrainSummary, NetError> {
    if !dist.is_main() {
        return Trainer::open_with_dist(opts, Some(dist))?.run(progress);
    }
    removing_new_folder_on_failure(&opts.out, || {
        Trainer::open_with_dist(opts, Some(dist))?.run(progress)
    })
}

/// Runs `run`; when it fails before it recorded anything — `out` did not exist before and
/// holds neither a checkpoint nor a `metrics.jsonl` (a wrong `--data`, a config no network can
/// be built with) — `out` is removed, so that such a failure leaves no folder behind. A run
/// that failed after it started logging (a non-finite loss) keeps its log for the diagnosis.
pub fn removing_new_folder_on_failure<T>(
    out: &Path,
    run: impl FnOnce() -> Result<T, NetError>,
) -> Result<T, NetError> {
    let existed = out.exists();
    let result = run();
    let recorded = out.join(LAST_CKPT).exists() || out.join(METRICS_FILE).exists();
    if result.is_err() && !existed && !recorded {
        let _ = std::fs::remove_dir_all(out);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entries(n: usize) -> Vec<IndexEntry> {
        (0..n)
            .map(|i| IndexEntry {
                sample_token: format!("{i:032x}"),
                scene_token: String::new(),
                scene_name: String::new(),
                splits: vec!["train".into()],
                conditions: vec![],
                dir: format!("{i:032x}"),
            })
            .collect()
    }

    #[test]
    fn training_subsets_are_nested_and_keep_the_partition_order() {
        let all = entries(50);
        let small = training_subset(&all, 10);
        let large = training_subset(&all, 30);
        assert_eq!((small.len(), large.len()), (10, 30));
        assert!(small.iter().all(|e| large.contains(e)), "nested");
        let pos = |e: &IndexEntry| all.iter().position(|x| x == e).unwrap();
        assert!(
            large.windows(2).all(|w| pos(&w[0]) < pos(&w[1])),
            "in order"
        );
        assert_ne!(small, all[..10].to_vec(), "not simply the first ten");
        assert_eq!(training_subset(&all, 50), all);
    }

    #[test]
    fn block_epochs_walk_consecutive_passes() {
        let train = entries(10);
        // 3 iterations of batch 4 per epoch: epochs 0..5 cover 60 draws = 6 passes.
        let stream: Vec<IndexEntry> = (0..5)
            .flat_map(|e| block_entries(&train, 7, e, 3, 4))
            .collect();
        assert_eq!(stream.len(), 60);
        for (p, pass) in stream.chunks(10).enumerate() {
            let mut tokens: Vec<&str> = pass.iter().map(|e| e.sample_token.as_str()).collect();
            let order = depthsense_data::epoch_order(10, 7, p as u64, true);
            assert_eq!(
                tokens,
                order
                    .iter()
                    .map(|&i| train[i].sample_token.as_str())
                    .collect::<Vec<_>>()
            );
            tokens.sort();
            tokens.dedup();
            assert_eq!(tokens.len(), 10, "pass {p} sees every sample once");
        }
    }
}
