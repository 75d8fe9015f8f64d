//! depthsense-train (layer 6, ARCHITECTURE.md): the training engine — optimisers, the training
//! step, checkpoints and exact resume, run folders, data-parallel training. Validation runs
//! through `depthsense_infer::run` (the network over samples, shared with `eval`), errors are
//! `depthsense_infer::NetError`.
//!
//! - [`trainer`]: `train` (RUN/ with config.json, metrics.jsonl, curves.png, checkpoints);
//! - [`metrics_log`]: RUN/metrics.jsonl — the one writer, reader and resume cut;
//! - [`step`]: the training step's forward and loss (`train` and `bench train` share it);
//! - [`learner`]: the one loop every training command drives, step by step ([`learner::fit`]);
//! - [`optim`]: the optimiser trait that [`adam`] (the PDA network) and [`sgd`] (SGD with
//!   momentum) implement, whose state can be saved (exact resume, [`optim_state`]);
//! - [`schedule`]: the learning rate and the dropout seed of an iteration;
//! - [`distributed`]: data-parallel training on c10d (Gloo / NCCL), `--nproc` launcher;
//! - [`bench`]: training and loader throughput.

pub mod adam;
pub mod bench;
pub mod distributed;
pub mod learner;
pub mod metrics_log;
pub mod optim;
pub mod optim_state;
pub mod run_folder;
pub mod schedule;
pub mod sgd;
pub mod step;
pub mod trainer;
