//! Data loader, training, evaluation, inference and the end-to-end demo.
//!
//! - [`distributed`]: data-parallel training on c10d (Gloo / NCCL), `--nproc` launcher;
//! - [`adam`], [`sgd`]: Adam (the PDA network) and SGD with momentum whose state can be saved (exact resume);
//! - [`trainer`]: `train` (RUN/ with config.json, metrics.jsonl, curves.png, checkpoints);
//! - [`validate`]: a network over samples into the metrics through the one scorer;
//! - [`evaluate`]: `eval` (SPEC §10 tables 1–3 as Markdown, CSV, JSON; radar drop);
//! - [`predict`]: depth for a prepared sample or raw files;
//! - [`demo`]: synth → prepare → train RGB-only and fusion → eval → report;
//! - [`experiments`]: SPEC §10 experiments from training runs (`ablation`: variants × seeds);
//! - [`mer`]: MER (SPEC §5): association labels, the PDA network's training, `mer apply`;
//! - [`report`]: one self-contained HTML page (+ Markdown, JSON) of every experiment output;
//! - [`bench`]: training and loader throughput.

pub mod adam;
pub mod bench;
pub mod demo;
pub mod distributed;
pub mod evaluate;
pub mod experiments;
pub mod explain;
pub mod mer;
mod optim_state;
pub mod outputs;
pub mod predict;
pub mod report;
pub mod sgd;
pub mod trainer;
pub mod validate;

/// The training stack's one error type (defined in `depthsense-data`, the lowest crate that
/// reports it): every message stays the same whichever crate raises it.
pub use depthsense_data::{error, TrainError};
