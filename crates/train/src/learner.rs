//! The training loop every training command drives — `train` ([`crate::trainer::Trainer`]) and
//! `mer train` (the PDA network, `depthsense-mer-train`) — step by step, in the manner of
//! burn-train's `Learner`:
//!
//! - a [`Learner`] says what one step does (a batch in, the network and optimiser updated:
//!   [`Learner::step`]), what a validation is, how an epoch's batches are drawn from any
//!   iteration on, and how the run is checkpointed and an epoch closed;
//! - [`fit`] owns the loop: the progress bar and its line (the learner's [`Learner::status`]
//!   and the step's images per second), the invocation's [`Clock`] (the time of the steps, the
//!   wait for their batches included, and of the validations; every epoch record's timings come
//!   from it), the validation of the initial network on a fresh
//!   run (`{"kind":"val","epoch":0,…}` in RUN/metrics.jsonl), the epochs still to run — a
//!   resumed run starts inside its epoch, at the batch after the last one done — the checkpoint
//!   cadence ([`Plan`]: every N iterations, at `--stop-after`), the epoch ends (validation,
//!   RUN/last.safetensors, then RUN/best.safetensors when it improved) and the rule for the best
//!   checkpoint ([`improves`]: the lowest [`Learner::score`], the initial network included);
//! - the data-parallel strategy ([`Learner::dist`]: one process, or a rank of a c10d job whose
//!   step all-reduces the gradients): the ranks agree on every stop;
//! - a stop signal (SIGINT / SIGTERM, [`depthsense_base::interrupt`]) ends the loop after the
//!   current step with a checkpoint that `--resume` continues from exactly ([`Fitted::signal`];
//!   at an epoch's last step the epoch is closed first, its validation included);
//! - [`Checkpointer`] writes RUN/last.safetensors with its optimiser state in the order that
//!   leaves a resumable pair whenever the process is killed ([`crate::optim_state`]);
//! - [`RunFolder`] is the run folder of the process that writes it: taken for one writer, a run
//!   never replaced silently, RUN/metrics.jsonl written through it.
//!
//! The learning rate and the step's dropout seed come from [`crate::schedule`], the optimiser
//! is a [`crate::optim::Optimizer`]. What differs between the two networks stays with them: the
//! batch, the loss, when a loss is read, the validation record (depth metrics vs. association
//! AUC) and its score (RMSE vs. −AUC), what a checkpoint holds, the epoch record.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use depthsense_base::interrupt::{self, StopSignal};
use depthsense_progress::Progress;
use depthsense_records::metrics_log::{EpochRecord, MetricsRecord, ValLine};
use serde::Serialize;

use crate::distributed::Dist;
use crate::optim_state;
use crate::run_folder::RunFolder;
use depthsense_dataset::outputs::{LAST_CKPT, LAST_OPTIM};
use depthsense_infer::NetError;

/// How long a run is, when [`fit`] writes RUN/last.safetensors inside an epoch (it always does
/// at an epoch's end) and where it stops.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Plan {
    /// Iterations per epoch (at least 1).
    pub iterations_per_epoch: u64,
    /// Epochs of the whole run.
    pub epochs: u64,
    /// Checkpoint every this many global iterations (0: only at epoch ends).
    pub checkpoint_every: u64,
    /// Stop after this global iteration, checkpointed (`--stop-after`; continue with
    /// `--resume`).
    pub stop_after: Option<u64>,
}

impl Plan {
    /// Iterations of the whole run (the progress bar's length).
    pub fn total_iterations(&self) -> u64 {
        self.iterations_per_epoch * self.epochs
    }
}

/// An epoch's batches from where the run stands ([`Learner::batches`]).
pub type Batches<B> = Box<dyn Iterator<Item = Result<B, NetError>>>;

/// One training run, driven step by step by [`fit`].
pub trait Learner {
    /// One validation record (the `"val"` field of RUN/metrics.jsonl's records); its
    /// `Display` is the progress line of a validation.
    type Val: Serialize + std::fmt::Display;
    /// What one step takes.
    type Batch;
    /// Global iterations done (0: a fresh run, whose initial network is validated first).
    fn iteration(&self) -> u64;
    /// When this invocation began (its set-up counts in the records' wall `seconds`).
    fn started(&self) -> Instant;
    /// The run's length, checkpoint cadence and stop.
    fn plan(&self) -> Plan;
    /// The current network on the validation samples, its record tagged with `epoch`: 0 before
    /// training, else the epoch just ended (1-based), which the learner's state then records.
    fn validation(&mut self, epoch: u64) -> Result<Self::Val, NetError>;
    /// A validation as the best-checkpoint rule ([`improves`]) sees it: lower is better (a
    /// depth network's RMSE; the PDA network's −AUC).
    fn score(v: &Self::Val) -> f64;
    /// The score of RUN/best.safetensors (kept in the learner's checkpointed state), `None`
    /// before the run's first validation.
    fn best_score(&self) -> Option<f64>;
    /// Records `v` as the best validation (its score, iteration and epoch) in the state that the
    /// next checkpoints carry.
    fn note_best(&mut self, v: &Self::Val);
    /// Writes RUN/best.safetensors (the process that writes RUN/ only).
    fn save_best(&mut self) -> Result<(), NetError>;
    /// The run folder, held by the process that writes RUN/ (`None`: a data-parallel rank
    /// other than 0).
    fn run_folder(&self) -> Option<&RunFolder>;
    /// Appends `record` to RUN/metrics.jsonl (only in the process that writes RUN/).
    fn log(&self, record: &serde_json::Value) -> Result<(), NetError> {
        match self.run_folder() {
            Some(folder) => folder.log(record),
            None => Ok(()),
        }
    }
    /// The batches of epoch `epoch` (0-based) after its first `skip` (done before a resume),
    /// at most the epoch's remaining iterations. The epoch's running loss starts here (from
    /// RUN/metrics.jsonl's records of the skipped iterations).
    fn batches(&mut self, epoch: u64, skip: u64) -> Result<Batches<Self::Batch>, NetError>;
    /// One training step on `batch`: the learning rate and dropout seed of the iteration
    /// ([`crate::schedule`]), forward, backward, optimiser step; says the global iteration
    /// after it and the images it trained on. A learner may defer reading the loss to
    /// [`Learner::flush`].
    fn step(
        &mut self,
        batch: Self::Batch,
        epoch: u64,
        progress: &Progress,
    ) -> Result<StepDone, NetError>;
    /// The last loss read and its learning rate, for the progress line (`loss 0.1234 lr
    /// 1.00e-3`).
    fn status(&self) -> String;
    /// Reads (and checks, and logs) the losses not read yet; [`fit`] calls it before anything
    /// is written and at an epoch's end.
    fn flush(&mut self, epoch: u64, progress: &Progress) -> Result<(), NetError>;
    /// Writes RUN/last.safetensors and its optimiser state, `epoch` epochs done.
    fn save_last(&mut self, epoch: u64) -> Result<(), NetError>;
    /// Writes epoch `epoch`'s (0-based) record, validated as `v`, checkpointed and timed as
    /// `timing`, to RUN/metrics.jsonl, and redraws RUN/curves.png.
    fn log_epoch(
        &mut self,
        epoch: u64,
        v: &Self::Val,
        timing: &EpochTiming,
    ) -> Result<(), NetError>;
    /// The stop signal this process has received (SIGINT / SIGTERM), asked after every step;
    /// [`fit`] makes the ranks of a data-parallel job agree on it ([`Learner::dist`]).
    fn stop_requested(&mut self) -> Result<Option<StopSignal>, NetError> {
        Ok(interrupt::requested())
    }
    /// The data-parallel strategy: this process's rank of a c10d job, or `None` for one
    /// process. The learner's step synchronises the gradients; [`fit`] makes the ranks stop
    /// together.
    fn dist(&self) -> Option<&Dist> {
        None
    }
}

/// What one [`Learner::step`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StepDone {
    /// The global iteration after the step.
    pub iteration: u64,
    /// Images it trained on (every rank's, in a data-parallel job).
    pub images: u64,
}

/// Where an invocation's time went, kept by [`fit`]: the training steps (each one's time runs
/// from the end of the previous one, so the wait for its batch is included), the validations
/// and the images trained on.
#[derive(Debug, Clone, Copy)]
pub struct Clock {
    started: Instant,
    /// Images trained on in this invocation.
    pub images: u64,
    /// Seconds in training steps and in validations, this invocation.
    pub train_secs: f64,
    pub val_secs: f64,
    /// `images` and `train_secs` when the current epoch began: the epoch's own rate, without
    /// the first epoch's warm-up (cuDNN autotuning, first allocations).
    epoch_mark: (u64, f64),
    /// When the previous step ended, or the epoch's batches were ready.
    step_ended: Instant,
}

/// The timings of an epoch record ([`Clock::close_epoch`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpochTiming {
    /// Images per second of the training steps of the invocation so far.
    pub images_per_s: f64,
    /// Images per second of this epoch's training steps.
    pub epoch_images_per_s: f64,
    pub train_seconds: f64,
    pub val_seconds: f64,
    /// Wall seconds of the invocation so far (its set-up included).
    pub seconds: f64,
}

impl EpochTiming {
    /// `record` with these timings.
    pub fn stamp<V>(&self, record: EpochRecord<V>) -> EpochRecord<V> {
        EpochRecord {
            images_per_s: Some(self.images_per_s),
            epoch_images_per_s: Some(self.epoch_images_per_s),
            train_seconds: Some(self.train_seconds),
            val_seconds: Some(self.val_seconds),
            seconds: Some(self.seconds),
            ..record
        }
    }
}

impl Clock {
    /// The clock of an invocation that began at `started`.
    pub fn new(started: Instant) -> Self {
        Self {
            started,
            images: 0,
            train_secs: 0.0,
            val_secs: 0.0,
            epoch_mark: (0, 0.0),
            step_ended: Instant::now(),
        }
    }

    /// Images per second of the training steps so far (0 before any).
    pub fn images_per_s(&self) -> f64 {
        self.images as f64 / self.train_secs.max(1e-9)
    }

    /// Wall seconds since the invocation began.
    pub fn seconds(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// An epoch's batches are ready: its first step's time starts here.
    fn batches_ready(&mut self) {
        self.step_ended = Instant::now();
    }

    /// A step of `images` ended: its time added; returns its own images per second.
    fn step_done(&mut self, images: u64) -> f64 {
        let now = Instant::now();
        let secs = now.duration_since(self.step_ended).as_secs_f64();
        self.step_ended = now;
        self.train_secs += secs;
        self.images += images;
        images as f64 / secs.max(1e-9)
    }

    /// The timings of the epoch that just ended; the next one's rate starts here.
    fn close_epoch(&mut self) -> EpochTiming {
        let (images0, secs0) = self.epoch_mark;
        self.epoch_mark = (self.images, self.train_secs);
        EpochTiming {
            images_per_s: self.images_per_s(),
            epoch_images_per_s: (self.images - images0) as f64
                / (self.train_secs - secs0).max(1e-9),
            train_seconds: self.train_secs,
            val_seconds: self.val_secs,
            seconds: self.seconds(),
        }
    }
}

/// What [`fit`] did.
pub struct Fitted<V> {
    /// Validation records in order: the initial network's (fresh runs), then one per epoch.
    pub val: Vec<V>,
    /// Stopped before the last epoch's end.
    pub interrupted: bool,
    /// The signal that stopped it (checkpointed first), when one did.
    pub signal: Option<StopSignal>,
    /// Where this invocation's time went.
    pub clock: Clock,
}

impl<V> Fitted<V> {
    fn stopped(val: Vec<V>, signal: Option<StopSignal>, clock: Clock) -> Self {
        Self {
            val,
            interrupted: true,
            signal,
            clock,
        }
    }
}

/// Why an epoch's steps ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum EpochStop {
    /// At the epoch's last step.
    End,
    /// At `--stop-after`, checkpointed.
    StopAfter,
    /// At a stop signal, checkpointed.
    Signal(StopSignal),
}

/// Runs `learner` to the end of its last epoch, or to its plan's `stop_after`.
pub fn fit<L: Learner>(learner: &mut L, progress: &Progress) -> Result<Fitted<L::Val>, NetError> {
    let plan = learner.plan();
    let mut clock = Clock::new(learner.started());
    progress.set_length(plan.total_iterations());
    progress.set_position(learner.iteration());
    let mut val = vec![];
    if learner.iteration() == 0 {
        progress.set_message("validating the initial network");
        let v = validate(learner, 0, &mut clock)?;
        // The network before training is a candidate for RUN/best.safetensors like every
        // epoch's: a fine-tuning that only makes it worse keeps its start.
        if improves(L::score(&v), learner.best_score()) {
            learner.note_best(&v);
            learner.save_best()?;
        }
        learner.log(&MetricsRecord::Val(ValLine::new(0, 0, &v)).to_value()?)?;
        progress.println(format!("validation before training: {v}"));
        val.push(v);
    }
    let (per_epoch, epochs) = (plan.iterations_per_epoch.max(1), plan.epochs);
    let mut pace = Pace::default();
    for epoch in learner.iteration() / per_epoch..epochs {
        // Nothing of this epoch done yet: a signal here needs no checkpoint (the last one, or
        // none at iteration 0, is where `--resume` starts).
        if let Some(sig) = stop_signal(learner)? {
            return Ok(Fitted::stopped(val, Some(sig), clock));
        }
        let mut steps = EpochSteps {
            epoch,
            plan: &plan,
            pace: &mut pace,
            clock: &mut clock,
            progress,
        };
        match steps.run(learner)? {
            EpochStop::StopAfter => return Ok(Fitted::stopped(val, None, clock)),
            EpochStop::Signal(sig) => return Ok(Fitted::stopped(val, Some(sig), clock)),
            EpochStop::End => {}
        }
        progress.set_message(format!("epoch {}/{epochs}: validating", epoch + 1));
        let v = close_epoch(learner, epoch, &mut clock)?;
        progress.println(format!(
            "validation after epoch {}/{epochs} (iteration {}): {v}",
            epoch + 1,
            learner.iteration()
        ));
        val.push(v);
        if plan.stop_after == Some(learner.iteration()) {
            return Ok(Fitted::stopped(val, None, clock));
        }
    }
    Ok(Fitted {
        val,
        interrupted: false,
        signal: None,
        clock,
    })
}

/// The progress line's loss text of a learner whose last read step had `last` (loss, learning
/// rate): `loss 0.1234 lr 1.00e-3`, or `loss –` before any.
pub fn loss_status(last: Option<(f64, f64)>) -> String {
    match last {
        Some((loss, lr)) => format!("loss {loss:.4} lr {lr:.2e}"),
        None => "loss –".into(),
    }
}

/// The stop signal of the job: this process's, or under data parallelism the one the ranks
/// agree on (all stop at the same iteration, or none).
fn stop_signal<L: Learner>(learner: &mut L) -> Result<Option<StopSignal>, NetError> {
    let local = learner.stop_requested()?;
    match learner.dist() {
        Some(d) => d.agree_on_stop(local),
        None => Ok(local),
    }
}

/// The rule for RUN/best.safetensors, the same for every learner: a run's first validation is
/// the best so far; a later one replaces it when its score is lower (a NaN never beats a number,
/// a number always beats a NaN).
pub fn improves(score: f64, best: Option<f64>) -> bool {
    match best {
        None => true,
        Some(b) if b.is_nan() => !score.is_nan(),
        Some(b) => score < b,
    }
}

/// [`Learner::validation`], its time added to the clock's validation seconds.
fn validate<L: Learner>(
    learner: &mut L,
    epoch: u64,
    clock: &mut Clock,
) -> Result<L::Val, NetError> {
    let t = Instant::now();
    let v = learner.validation(epoch);
    clock.val_secs += t.elapsed().as_secs_f64();
    v
}

/// Closes epoch `epoch` (0-based) after its last step: validation, the best rule, the
/// checkpoints (RUN/last.safetensors always, RUN/best.safetensors when it improved, both with
/// the state that says so) and the epoch's record with its timings.
fn close_epoch<L: Learner>(
    learner: &mut L,
    epoch: u64,
    clock: &mut Clock,
) -> Result<L::Val, NetError> {
    let v = validate(learner, epoch + 1, clock)?;
    let improved = improves(L::score(&v), learner.best_score());
    if improved {
        learner.note_best(&v);
    }
    learner.save_last(epoch + 1)?;
    if improved {
        learner.save_best()?;
    }
    learner.log_epoch(epoch, &v, &clock.close_epoch())?;
    Ok(v)
}

/// The steps of one epoch from where the run stands.
struct EpochSteps<'a> {
    epoch: u64,
    plan: &'a Plan,
    pace: &'a mut Pace,
    clock: &'a mut Clock,
    progress: &'a Progress,
}

impl EpochSteps<'_> {
    /// To the epoch's end, to `stop_after` or to a stop signal (both checkpointed). Its losses
    /// are all read when it returns.
    fn run<L: Learner>(&mut self, learner: &mut L) -> Result<EpochStop, NetError> {
        let (epoch, plan, progress) = (self.epoch, self.plan, self.progress);
        let per_epoch = plan.iterations_per_epoch.max(1);
        let skip = learner.iteration() - epoch * per_epoch;
        let batches = learner.batches(epoch, skip)?;
        self.clock.batches_ready();
        for batch in batches {
            let done = learner.step(batch?, epoch, progress)?;
            let (it, rate) = (done.iteration, self.clock.step_done(done.images));
            if let Some(line) = self.pace.step(it, plan) {
                progress.println(line);
            }
            let epoch_end = it.is_multiple_of(per_epoch);
            let stop_here = plan.stop_after == Some(it);
            let periodic = plan.checkpoint_every > 0 && it.is_multiple_of(plan.checkpoint_every);
            // At an epoch's last step the epoch is closed (validated, checkpointed) first.
            let signal = if epoch_end {
                None
            } else {
                stop_signal(learner)?
            };
            // Losses are read (and checked) before anything is written.
            if epoch_end || stop_here || periodic || signal.is_some() {
                learner.flush(epoch, progress)?;
            }
            // After the read, so that a progress line carries this iteration's loss.
            progress.set_message(format!(
                "epoch {}/{} {} {rate:.1} img/s",
                epoch + 1,
                plan.epochs,
                learner.status()
            ));
            progress.set_position(it);
            if !epoch_end && (stop_here || periodic || signal.is_some()) {
                learner.save_last(epoch)?;
                if let Some(sig) = signal {
                    return Ok(EpochStop::Signal(sig));
                }
                if stop_here {
                    return Ok(EpochStop::StopAfter);
                }
            }
        }
        learner.flush(epoch, progress)?;
        Ok(EpochStop::End)
    }
}

/// Steps timed before the run says how long an epoch takes (after the first, untimed one).
const PACE_STEPS: u64 = 5;

/// The time of an epoch, measured on this invocation's first steps and said once: a run on a
/// machine too slow for its network says so within a few steps, not after an epoch.
#[derive(Default)]
struct Pace {
    /// When the first step of this invocation ended (its own time is set-up: not counted).
    first: Option<(Instant, u64)>,
    said: bool,
}

impl Pace {
    /// After the step that reached iteration `it`: the line to print, once.
    fn step(&mut self, it: u64, plan: &Plan) -> Option<String> {
        if self.said {
            return None;
        }
        let now = Instant::now();
        let Some((t0, it0)) = self.first else {
            self.first = Some((now, it));
            return None;
        };
        let timed = it.saturating_sub(it0);
        if timed < PACE_STEPS {
            return None;
        }
        self.said = true;
        let per_step = now.duration_since(t0).as_secs_f64() / timed as f64;
        let left = plan.total_iterations().saturating_sub(it);
        Some(format!(
            "pace: {per_step:.2} s per iteration over iterations {}–{it} → an epoch of {} \
             iterations ≈ {}, the {left} iterations left ≈ {} (validations not included)",
            it0 + 1,
            plan.iterations_per_epoch,
            depthsense_progress::human(Duration::from_secs_f64(
                per_step * plan.iterations_per_epoch as f64
            )),
            depthsense_progress::human(Duration::from_secs_f64(per_step * left as f64)),
        ))
    }
}

/// RUN/last.safetensors and its optimiser state RUN/last.optim.safetensors, written so that a
/// kill at any point leaves a pair that belongs together: the optimiser state first, its
/// predecessor kept beside it until the checkpoint is written ([`optim_state::rotate`];
/// `--resume` picks the matching one with [`optim_state::load_matching`]).
pub struct Checkpointer {
    run: PathBuf,
    /// Whether RUN/last.optim.safetensors belongs to RUN/last.safetensors (false after a
    /// resume from the `.prev` state: the newer file is stale).
    optim_matches: bool,
}

impl Checkpointer {
    /// The checkpointer of run folder `run`; `optim_matches` as [`optim_state::load_matching`]
    /// found it (true for a fresh run).
    pub fn new(run: &Path, optim_matches: bool) -> Self {
        Self {
            run: run.to_path_buf(),
            optim_matches,
        }
    }

    /// Writes the optimiser state with `write_optim(path)`, then the network with
    /// `write_model(path)`.
    pub fn save_last(
        &mut self,
        write_optim: impl FnOnce(&Path) -> Result<(), NetError>,
        write_model: impl FnOnce(&Path) -> Result<(), NetError>,
    ) -> Result<(), NetError> {
        let optim = self.run.join(LAST_OPTIM);
        optim_state::rotate(&optim, self.optim_matches)?;
        self.optim_matches = false;
        write_optim(&optim)?;
        write_model(&self.run.join(LAST_CKPT))?;
        self.optim_matches = true;
        // The pair on disk belongs together now: the state kept for a kill in between goes.
        let prev = optim_state::prev_path(&optim);
        if prev.exists() {
            std::fs::remove_file(&prev).map_err(|e| NetError::io(&prev, e))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use depthsense_dataset::outputs::PREV_OPTIM;
    use std::cell::RefCell;

    /// A learner that records what `fit` asked of it: 10 iterations per epoch.
    struct Toy {
        iteration: u64,
        plan: Plan,
        calls: RefCell<Vec<String>>,
        /// A SIGTERM arrives during this iteration's step.
        signal_at: Option<u64>,
        /// The validation after epoch N is `vals[N]` (default 100 + N).
        vals: Vec<u64>,
        best: Option<f64>,
        /// Steps of this invocation (2 images each).
        steps: u64,
    }

    impl Toy {
        fn call(&self, c: String) {
            self.calls.borrow_mut().push(c);
        }
    }

    impl Learner for Toy {
        type Val = u64;
        type Batch = u64;
        fn iteration(&self) -> u64 {
            self.iteration
        }
        fn started(&self) -> Instant {
            Instant::now()
        }
        fn plan(&self) -> Plan {
            self.plan
        }
        fn validation(&mut self, epoch: u64) -> Result<u64, NetError> {
            self.call(format!("validate {epoch}"));
            Ok(self
                .vals
                .get(epoch as usize)
                .copied()
                .unwrap_or(100 + epoch))
        }
        fn score(v: &u64) -> f64 {
            *v as f64
        }
        fn best_score(&self) -> Option<f64> {
            self.best
        }
        fn note_best(&mut self, v: &u64) {
            self.best = Some(*v as f64);
        }
        fn save_best(&mut self) -> Result<(), NetError> {
            self.call(format!("best {:?} at {}", self.best, self.iteration));
            Ok(())
        }
        fn run_folder(&self) -> Option<&RunFolder> {
            None
        }
        fn log(&self, record: &serde_json::Value) -> Result<(), NetError> {
            self.call(record.to_string());
            Ok(())
        }
        fn batches(&mut self, epoch: u64, skip: u64) -> Result<Batches<u64>, NetError> {
            self.call(format!("epoch {epoch} from {skip}"));
            Ok(Box::new((epoch * 10 + skip..epoch * 10 + 10).map(Ok)))
        }
        fn step(&mut self, batch: u64, _: u64, _: &Progress) -> Result<StepDone, NetError> {
            assert_eq!(
                batch, self.iteration,
                "batches in order, none skipped twice"
            );
            self.iteration += 1;
            self.steps += 1;
            Ok(StepDone {
                iteration: self.iteration,
                images: 2,
            })
        }
        fn status(&self) -> String {
            format!("loss {}", self.iteration)
        }
        fn flush(&mut self, _: u64, _: &Progress) -> Result<(), NetError> {
            self.call(format!("flush {}", self.iteration));
            Ok(())
        }
        fn save_last(&mut self, epoch: u64) -> Result<(), NetError> {
            self.call(format!("save {epoch} at {}", self.iteration));
            Ok(())
        }
        fn log_epoch(&mut self, epoch: u64, v: &u64, t: &EpochTiming) -> Result<(), NetError> {
            let images = t.images_per_s * t.train_seconds.max(1e-9);
            let expected = 2.0 * self.steps as f64;
            assert!(
                (images - expected).abs() <= 1e-6 * expected,
                "every step's images counted: {images} vs {expected}"
            );
            assert!(t.epoch_images_per_s > 0.0 && t.seconds >= t.train_seconds);
            self.call(format!("end {epoch}: {v}"));
            Ok(())
        }
        fn stop_requested(&mut self) -> Result<Option<StopSignal>, NetError> {
            let signalled = self.signal_at.is_some_and(|at| self.iteration >= at);
            Ok(signalled.then_some(StopSignal::Terminate))
        }
    }

    fn toy(iteration: u64, epochs: u64, checkpoint_every: u64, stop_after: Option<u64>) -> Toy {
        Toy {
            iteration,
            plan: Plan {
                iterations_per_epoch: 10,
                epochs,
                checkpoint_every,
                stop_after,
            },
            calls: RefCell::new(vec![]),
            signal_at: None,
            vals: vec![],
            best: None,
            steps: 0,
        }
    }

    fn calls(t: Toy) -> Vec<String> {
        // The flushes at epoch ends only: a flush after every step would not be a deferred read.
        t.calls.into_inner()
    }

    #[test]
    fn a_fresh_run_validates_the_initial_network_then_every_epoch() {
        let mut t = toy(0, 2, 0, None);
        let f = fit(&mut t, &Progress::hidden()).unwrap();
        assert_eq!(f.val, [100, 101, 102]);
        assert!(!f.interrupted);
        assert_eq!(
            calls(t),
            [
                "validate 0",
                "best Some(100.0) at 0",
                r#"{"epoch":0,"format_version":2,"iteration":0,"kind":"val","val":100}"#,
                "epoch 0 from 0",
                "flush 10",
                "flush 10",
                "validate 1",
                "save 1 at 10",
                "end 0: 101",
                "epoch 1 from 0",
                "flush 20",
                "flush 20",
                "validate 2",
                "save 2 at 20",
                "end 1: 102"
            ]
        );
    }

    #[test]
    fn a_resumed_run_starts_inside_its_epoch_and_stop_after_checkpoints_and_ends_it() {
        let mut t = toy(15, 4, 4, Some(27));
        let f = fit(&mut t, &Progress::hidden()).unwrap();
        assert_eq!(f.val, [102]);
        assert!(f.interrupted);
        assert_eq!(t.iteration, 27);
        assert_eq!(
            calls(t),
            [
                "epoch 1 from 5",
                "flush 16",
                "save 1 at 16",
                "flush 20",
                "flush 20",
                "validate 2",
                "save 2 at 20",
                "best Some(102.0) at 20",
                "end 1: 102",
                "epoch 2 from 0",
                "flush 24",
                "save 2 at 24",
                "flush 27",
                "save 2 at 27"
            ]
        );
    }

    #[test]
    fn a_signal_checkpoints_after_the_current_step_and_stops() {
        let mut t = toy(0, 3, 0, None);
        t.signal_at = Some(13);
        let f = fit(&mut t, &Progress::hidden()).unwrap();
        assert!(f.interrupted);
        assert_eq!(f.signal, Some(StopSignal::Terminate));
        assert_eq!(t.iteration, 13);
        assert!(calls(t).ends_with(&[
            "end 0: 101".to_string(),
            "epoch 1 from 0".into(),
            "flush 13".into(),
            "save 1 at 13".into()
        ]));
    }

    #[test]
    fn a_signal_at_an_epoch_end_closes_the_epoch_then_stops() {
        let mut t = toy(0, 3, 0, None);
        t.signal_at = Some(10);
        let f = fit(&mut t, &Progress::hidden()).unwrap();
        assert_eq!(
            (f.signal, f.val),
            (Some(StopSignal::Terminate), vec![100, 101])
        );
        assert_eq!(t.iteration, 10);
        assert!(calls(t).ends_with(&[
            "flush 10".to_string(),
            "validate 1".into(),
            "save 1 at 10".into(),
            "end 0: 101".into()
        ]));
    }

    #[test]
    fn stop_after_at_an_epoch_end_closes_the_epoch_first() {
        let mut t = toy(0, 3, 0, Some(10));
        let f = fit(&mut t, &Progress::hidden()).unwrap();
        assert_eq!(f.val, [100, 101]);
        assert!(f.interrupted);
        assert!(calls(t).ends_with(&[
            "flush 10".to_string(),
            "validate 1".into(),
            "save 1 at 10".into(),
            "end 0: 101".into()
        ]));
    }

    #[test]
    fn the_best_checkpoint_is_the_lowest_score_the_initial_network_included() {
        let mut t = toy(0, 3, 0, None);
        t.vals = vec![5, 3, 4, 3];
        let f = fit(&mut t, &Progress::hidden()).unwrap();
        assert_eq!(f.val, [5, 3, 4, 3]);
        let bests: Vec<_> = calls(t)
            .into_iter()
            .filter(|c| c.starts_with("best"))
            .collect();
        // A tie keeps the earlier checkpoint.
        assert_eq!(bests, ["best Some(5.0) at 0", "best Some(3.0) at 10"]);
        assert!(improves(1.0, Some(f64::NAN)) && !improves(f64::NAN, Some(1.0)));
        assert!(improves(f64::NAN, None) && !improves(2.0, Some(2.0)));
    }

    #[test]
    fn a_kill_between_the_two_writes_leaves_the_matching_optimiser_state() {
        let d = tempfile::tempdir().unwrap();
        let (optim, prev, last) = (
            d.path().join(LAST_OPTIM),
            d.path().join(PREV_OPTIM),
            d.path().join(LAST_CKPT),
        );
        let write = |text: &'static str| {
            move |p: &Path| -> Result<(), NetError> {
                std::fs::write(p, text).map_err(|e| NetError::io(p, e))
            }
        };
        let mut c = Checkpointer::new(d.path(), true);
        c.save_last(write("optim 1"), write("model 1")).unwrap();
        assert!(!prev.exists());
        // killed after the optimiser state of iteration 2, before its checkpoint
        let killed = c.save_last(write("optim 2"), |_: &Path| {
            Err(NetError::io(
                Path::new("killed"),
                std::io::Error::other("killed"),
            ))
        });
        assert!(killed.is_err());
        let read = |p: &Path| std::fs::read_to_string(p).unwrap();
        assert_eq!(
            (read(&optim), read(&prev), read(&last)),
            ("optim 2".into(), "optim 1".into(), "model 1".into())
        );
        // the next save drops the stale state and keeps the one that matches the checkpoint
        let mut resumed = Checkpointer::new(d.path(), false);
        resumed
            .save_last(write("optim 3"), |_: &Path| {
                Err(NetError::io(
                    Path::new("killed"),
                    std::io::Error::other("killed"),
                ))
            })
            .unwrap_err();
        assert_eq!(
            (read(&optim), read(&prev)),
            ("optim 3".into(), "optim 1".into())
        );
        resumed
            .save_last(write("optim 3"), write("model 3"))
            .unwrap();
        assert_eq!(
            (read(&optim), read(&last)),
            ("optim 3".into(), "model 3".into())
        );
        assert!(!prev.exists(), "a consistent pair keeps no previous state");
    }
}
