//! depthsense-train (layer 6, ARCHITECTURE.md): the training engine — optimisers, the training
//! step, checkpoints and exact resume, run folders, data-parallel training. Validation runs
//! through `depthsense_infer::run` (the network over samples, shared with `eval`), errors are
//! `depthsense_infer::NetError`.
//!
//! - [`trainer`]: `train` (RUN/ with config.json, metrics.jsonl, curves.png, checkpoints);
//! - [`metrics_log`]: RUN/metrics.jsonl — the one writer, reader and resume cut;
//! - [`step`]: the training step's forward and loss (`train` and `bench train` share it);
//! - [`adam`], [`sgd`]: Adam (the PDA network) and SGD with momentum, whose state can be saved
//!   (exact resume, [`optim_state`]);
//! - [`distributed`]: data-parallel training on c10d (Gloo / NCCL), `--nproc` launcher;
//! - [`bench`]: training and loader throughput.

pub mod adam;
pub mod bench;
pub mod distributed;
pub mod learner;
pub mod metrics_log;
pub mod optim_state;
pub mod sgd;
pub mod step;
pub mod trainer;
