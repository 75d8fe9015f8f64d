//! depthsense-train (layer 5, ARCHITECTURE.md): the training engine — optimisers, the training
//! step, validation, checkpoints and exact resume, run folders, data-parallel training.
//!
//! - [`trainer`]: `train` (RUN/ with config.json, metrics.jsonl, curves.png, checkpoints);
//! - [`upload`]: a batch onto the device (pinned host memory on CUDA);
//! - [`metrics_log`]: RUN/metrics.jsonl — the one writer, reader and resume cut;
//! - [`step`]: the training step's forward and loss (`train` and `bench train` share it);
//! - [`validate`]: a network over samples into the metrics through the one scorer;
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
pub mod upload;
pub mod validate;

mod error;
/// The training stack's one error type: every message stays the same whichever crate raises it.
pub use error::TrainError;
