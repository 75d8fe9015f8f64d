//! Data loader, training, evaluation, inference and the end-to-end demo.
//!
//! - [`data`]: reads `depthsense prepare` output, SPEC §8 augmentation, parallel prefetching
//!   loader, deterministic train/validation partition;
//! - [`distributed`]: data-parallel training on c10d (Gloo / NCCL), `--nproc` launcher;
//! - [`sgd`]: SGD with momentum whose state can be saved (exact resume);
//! - [`trainer`]: `train` (RUN/ with config.json, metrics.jsonl, curves.png, checkpoints);
//! - [`evaluate`]: `eval` (SPEC §10 tables 1–3 as Markdown, CSV, JSON; radar drop);
//! - [`predict`]: depth for a prepared sample or raw files;
//! - [`demo`]: synth → prepare → train RGB-only and fusion → eval → report;
//! - [`experiments`]: SPEC §10 experiments from training runs (`ablation`: variants × seeds);
//! - [`mer`]: MER (SPEC §5): association labels, the PDA network's training, `mer apply`;
//! - [`report`]: one self-contained HTML page (+ Markdown, JSON) of every experiment output;
//! - [`bench`]: training and loader throughput;
//! - [`plot`]: curves and depth pictures.

pub mod bench;
pub mod data;
pub mod demo;
pub mod distributed;
pub mod error;
pub mod evaluate;
pub mod experiments;
pub mod explain;
pub mod mer;
mod optim_state;
pub mod outputs;
pub mod plot;
pub mod predict;
pub mod report;
pub mod sgd;
pub mod trainer;

pub use error::TrainError;

/// serde `skip_serializing_if` for optional settings that are off at their default (0, false,
/// empty): the JSON of runs that do not use them stays as it was before they existed.
pub(crate) fn is_default<T: Default + PartialEq>(v: &T) -> bool {
    *v == T::default()
}
