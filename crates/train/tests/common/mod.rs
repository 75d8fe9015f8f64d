//! Set-up shared by the experiment tests (`ablation.rs`, `reduced_data.rs`): a hidden progress
//! host, file modification times (resume checks) and quick run settings on a toy dataset.
#![allow(dead_code)] // each test binary uses its own part

use std::path::Path;
use std::time::SystemTime;

use depthsense_train::experiments::runner::RunSettings;
use indicatif::{MultiProgress, ProgressDrawTarget};

pub fn hidden() -> MultiProgress {
    MultiProgress::with_draw_target(ProgressDrawTarget::hidden())
}

pub fn mtime(p: &Path) -> SystemTime {
    std::fs::metadata(p).unwrap().modified().unwrap()
}

/// The `tiny` preset at reduced widths, no dropout: seconds per run on 2 cores.
pub fn small_model() -> Vec<String> {
    [
        "width=8",
        "decoder-channels=16",
        "head-channels=16",
        "radar-width=8",
        "dropout=0",
    ]
    .map(String::from)
    .to_vec()
}

/// One epoch of two batches of two, validated on two samples, on the CPU.
pub fn quick_runs(data: &Path) -> RunSettings {
    RunSettings {
        data: data.to_path_buf(),
        preset: "tiny".into(),
        set: small_model(),
        epochs: 1,
        batch_size: 2,
        lr: 2e-3,
        device: "cpu".into(),
        jobs: 2,
        max_val_samples: Some(2),
        max_batches_per_epoch: Some(2),
        ..RunSettings::default()
    }
}
