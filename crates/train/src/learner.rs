//! The training loop every training command drives — `train` ([`crate::trainer::Trainer`]) and
//! `mer train` (the PDA network, `depthsense-mer`) — in the manner of burn-train's `Learner`:
//!
//! - a [`Learner`] says how to validate the current network, how to log a record and how to
//!   train one epoch and close it (validation, checkpoints, the epoch record);
//! - [`fit`] runs it: the progress bar, the validation of the initial network on a fresh run
//!   (`{"kind":"val","epoch":0,…}` in RUN/metrics.jsonl), then the epochs still to run, stopping
//!   where an epoch says so (`--stop-after`);
//! - [`Checkpointer`] writes RUN/last.safetensors with its optimiser state in the order that
//!   leaves a resumable pair whenever the process is killed ([`crate::optim_state`]);
//! - [`lock_run_folder`] takes the run folder for one writer and refuses to replace a run
//!   silently ([`crate::outputs`]).
//!
//! What differs between the two networks stays with them: the batch, the step, the loss, the
//! validation record (depth metrics vs. association AUC), the best-checkpoint rule.

use std::ops::Range;
use std::path::{Path, PathBuf};

use depthsense_base::lock::OutputLock;
use depthsense_progress::Progress;
use serde::Serialize;

use crate::optim_state;
use depthsense_dataset::outputs::{claim_run_folder, LAST_CKPT, LAST_OPTIM};
use depthsense_infer::NetError;

/// How one training run validates, logs and trains an epoch; [`fit`] drives it.
pub trait Learner {
    /// One validation record (the `"val"` field of RUN/metrics.jsonl's records); its
    /// `Display` is the progress line of a validation.
    type Val: Serialize + std::fmt::Display;
    /// Global iterations done (0: a fresh run, whose initial network is validated first).
    fn iteration(&self) -> u64;
    /// Iterations of the whole run (the progress bar's length).
    fn total_iterations(&self) -> u64;
    /// The epochs still to run (a resumed run starts inside or after its last epoch).
    fn epochs_left(&self) -> Range<u64>;
    /// The current network on the validation samples, its record tagged with `epoch`.
    fn validation(&mut self, epoch: u64) -> Result<Self::Val, NetError>;
    /// Appends `record` to RUN/metrics.jsonl (only in the process that writes RUN/).
    fn log(&self, record: &serde_json::Value) -> Result<(), NetError>;
    /// Trains epoch `epoch` (0-based) and closes it: validation, checkpoints, epoch record.
    fn train_epoch(
        &mut self,
        epoch: u64,
        progress: &Progress,
    ) -> Result<EpochEnd<Self::Val>, NetError>;
}

/// How an epoch ended.
pub struct EpochEnd<V> {
    /// Its validation record (None when it was interrupted before its end).
    pub val: Option<V>,
    /// Stop here (`--stop-after` reached): the run continues with `--resume`.
    pub stop: bool,
}

/// What [`fit`] did.
pub struct Fitted<V> {
    /// Validation records in order: the initial network's (fresh runs), then one per epoch.
    pub val: Vec<V>,
    /// Stopped before the last epoch's end.
    pub interrupted: bool,
}

/// Runs `learner` to the end of its last epoch, or to where an epoch says stop.
pub fn fit<L: Learner>(learner: &mut L, progress: &Progress) -> Result<Fitted<L::Val>, NetError> {
    progress.set_length(learner.total_iterations());
    progress.set_position(learner.iteration());
    let mut val = vec![];
    if learner.iteration() == 0 {
        progress.set_message("validating the initial network");
        let v = learner.validation(0)?;
        learner.log(&serde_json::json!({"kind": "val", "epoch": 0, "iteration": 0, "val": v}))?;
        progress.println(format!("validation before training: {v}"));
        val.push(v);
    }
    let epochs = learner.epochs_left();
    for epoch in epochs.clone() {
        let end = learner.train_epoch(epoch, progress)?;
        if let Some(v) = &end.val {
            progress.println(format!(
                "validation after epoch {}/{} (iteration {}): {v}",
                epoch + 1,
                epochs.end,
                learner.iteration()
            ));
        }
        val.extend(end.val);
        if end.stop {
            return Ok(Fitted {
                val,
                interrupted: true,
            });
        }
    }
    Ok(Fitted {
        val,
        interrupted: false,
    })
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

/// Takes run folder `out` for `depthsense {command}` alone ([`OutputLock`]) and refuses a
/// folder that holds a run unless `resume` or `force` ([`claim_run_folder`]). The lock is held
/// while the returned value lives.
pub fn lock_run_folder(
    out: &Path,
    command: &str,
    resume: bool,
    force: bool,
) -> Result<OutputLock, NetError> {
    let lock = OutputLock::exclusive(out, &format!("depthsense {command}"))?;
    claim_run_folder(out, command, resume, force)?;
    Ok(lock)
}

#[cfg(test)]
mod tests {
    use super::*;
    use depthsense_dataset::outputs::PREV_OPTIM;
    use std::cell::RefCell;

    /// A learner that records what `fit` asked of it.
    struct Toy {
        iteration: u64,
        epochs: Range<u64>,
        stop_at_epoch: Option<u64>,
        calls: RefCell<Vec<String>>,
    }

    impl Learner for Toy {
        type Val = u64;
        fn iteration(&self) -> u64 {
            self.iteration
        }
        fn total_iterations(&self) -> u64 {
            10 * self.epochs.end
        }
        fn epochs_left(&self) -> Range<u64> {
            self.epochs.clone()
        }
        fn validation(&mut self, epoch: u64) -> Result<u64, NetError> {
            self.calls.borrow_mut().push(format!("validate {epoch}"));
            Ok(100 + epoch)
        }
        fn log(&self, record: &serde_json::Value) -> Result<(), NetError> {
            self.calls.borrow_mut().push(record.to_string());
            Ok(())
        }
        fn train_epoch(&mut self, epoch: u64, _: &Progress) -> Result<EpochEnd<u64>, NetError> {
            self.calls.borrow_mut().push(format!("epoch {epoch}"));
            self.iteration += 10;
            let stop = self.stop_at_epoch == Some(epoch);
            Ok(EpochEnd {
                val: (!stop).then_some(101 + epoch),
                stop,
            })
        }
    }

    fn toy(iteration: u64, epochs: Range<u64>, stop_at_epoch: Option<u64>) -> Toy {
        Toy {
            iteration,
            epochs,
            stop_at_epoch,
            calls: RefCell::new(vec![]),
        }
    }

    #[test]
    fn a_fresh_run_validates_the_initial_network_then_every_epoch() {
        let mut t = toy(0, 0..2, None);
        let f = fit(&mut t, &Progress::hidden()).unwrap();
        assert_eq!(f.val, [100, 101, 102]);
        assert!(!f.interrupted);
        assert_eq!(
            t.calls.into_inner(),
            [
                "validate 0",
                r#"{"epoch":0,"iteration":0,"kind":"val","val":100}"#,
                "epoch 0",
                "epoch 1"
            ]
        );
    }

    #[test]
    fn a_resumed_run_skips_the_initial_validation_and_a_stop_ends_it() {
        let mut t = toy(15, 1..4, Some(2));
        let f = fit(&mut t, &Progress::hidden()).unwrap();
        assert_eq!(f.val, [102]);
        assert!(f.interrupted);
        assert_eq!(t.calls.into_inner(), ["epoch 1", "epoch 2"]);
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
            Err(NetError::Other("killed".into()))
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
                Err(NetError::Other("killed".into()))
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
