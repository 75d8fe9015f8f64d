//! `depthsense eval`: a checkpoint on prepared data → the tables of SPEC §10 items 1–3 as
//! Markdown, CSV and JSON, with the number of images and pixels behind each row; radar drop
//! for the sensor-failure ablation (SPEC §10.8).

use std::path::{Path, PathBuf};

use depthsense_metrics::{tables, EvalConfig, Report};
use depthsense_model::checkpoint;
use depthsense_nuscenes::fsutil::write_atomic;
use depthsense_prep::layout::IndexEntry;
use indicatif::ProgressBar;
use serde::{Deserialize, Serialize};

use crate::data::{partition, Dataset, LoadOptions, RadarInput};
use crate::error::TrainError;
use crate::trainer::{evaluate_net, radar_input_for, subsample};

/// Which samples to evaluate.
pub const HELD_OUT: &str = "held-out";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalOptions {
    pub checkpoint: PathBuf,
    pub data: PathBuf,
    /// "held-out" (default: the `test` split, or the scenes `train` held out), "all", or a
    /// split name of the index (test-night, official-val, …).
    pub split: String,
    /// Scene modulo used by `train` when no split lists match (must equal train's).
    pub val_every_scene: usize,
    pub eval: EvalConfig,
    /// Fraction of radar points removed (1.0 = radar absent).
    pub radar_drop: f64,
    pub seed: u64,
    pub batch_size: usize,
    pub device: String,
    pub jobs: usize,
    pub max_samples: Option<usize>,
    /// Radar map(s) (None = derived from the model config).
    pub radar_input: Option<RadarInput>,
    /// Model name in the tables.
    pub name: String,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            checkpoint: PathBuf::from("runs/train/best.safetensors"),
            data: PathBuf::from("prepared"),
            split: HELD_OUT.into(),
            val_every_scene: 5,
            eval: EvalConfig::default(),
            radar_drop: 0.0,
            seed: 0,
            batch_size: 4,
            device: "auto".into(),
            jobs: 0,
            max_samples: None,
            radar_input: None,
            name: "model".into(),
        }
    }
}

/// Samples of a split name (see [`EvalOptions::split`]).
pub fn select_split(
    ds: &Dataset,
    split: &str,
    every: usize,
) -> Result<Vec<IndexEntry>, TrainError> {
    let v = if split == HELD_OUT {
        partition(ds, every)?.val
    } else {
        ds.split(split)
    };
    if v.is_empty() {
        return Err(TrainError::Data(format!(
            "{}: split {split:?} has no samples (splits present: {:?})",
            ds.root.display(),
            ds.split_names()
        )));
    }
    Ok(v)
}

/// Evaluate a checkpoint. Returns the report (every row).
pub fn run_eval(opts: &EvalOptions, progress: &ProgressBar) -> Result<Report, TrainError> {
    if !(0.0..=1.0).contains(&opts.radar_drop) {
        return Err(TrainError::Config(format!(
            "--radar-drop must be within [0, 1], got {}",
            opts.radar_drop
        )));
    }
    let device = depthsense_model::device::parse_device(&opts.device)?;
    let loaded = checkpoint::load(&opts.checkpoint, device)?;
    let ds = Dataset::open(&opts.data)?;
    let entries = subsample(
        &select_split(&ds, &opts.split, opts.val_every_scene)?,
        opts.max_samples,
    );
    let radar = radar_input_for(&loaded.config, opts.radar_input)?;
    let load = LoadOptions {
        radar: radar.unwrap_or_default(),
        no_radar: radar.is_none(),
        radar_drop: opts.radar_drop,
        seed: opts.seed,
        ..LoadOptions::default()
    };
    progress.set_length(entries.len() as u64);
    evaluate_net(
        &loaded.net,
        &ds,
        &entries,
        &load,
        &opts.eval,
        opts.batch_size,
        opts.jobs,
        device,
        progress,
        |_, _| Ok(()),
    )
}

/// Write `tables.md`, `tables.csv` and `tables.json` (every row of every report plus the
/// three rendered tables) into `dir`.
pub fn write_tables(dir: &Path, models: &[(&str, &Report)]) -> Result<(), TrainError> {
    std::fs::create_dir_all(dir).map_err(|e| TrainError::io(dir, e))?;
    let md = tables::markdown_report(models);
    let csv = tables::csv_report(models);
    let json = serde_json::json!({
        "models": models.iter().map(|(n, r)| serde_json::json!({"name": n, "report": r})).collect::<Vec<_>>(),
        "tables": tables::all_tables(models),
    });
    let w = |name: &str, bytes: &[u8]| {
        let p = dir.join(name);
        write_atomic(&p, bytes).map_err(|e| TrainError::io(&p, e))
    };
    w("tables.md", md.as_bytes())?;
    w("tables.csv", csv.as_bytes())?;
    w(
        "tables.json",
        serde_json::to_string_pretty(&json)
            .map_err(|e| TrainError::Other(e.to_string()))?
            .as_bytes(),
    )
}
