//! MER maps on disk (SPEC §5): the torch-free format in [`depthsense_dataset::mer_maps`]
//! (re-exported) and `mer.json`, the record of the PDA model behind them (its config is the
//! model crate's).

use std::path::Path;

use serde::{Deserialize, Serialize};

pub use depthsense_dataset::mer_maps::*;

use crate::error::TrainError;

/// `O/mer.json`: the model behind the MER maps of a prepared directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MerRecord {
    /// Checkpoint path as given to `mer apply`.
    pub checkpoint: String,
    /// FNV-1a 64 of the checkpoint bytes (hex): the identity of the model.
    pub checkpoint_fnv64: String,
    /// The PDA config stored in the checkpoint.
    pub pda: depthsense_model::pda::PdaConfig,
    pub thresholds: Vec<f32>,
    pub depth_file: String,
    pub conf_file: String,
}

/// Reads `O/mer.json` when present.
pub fn read_record(root: &Path) -> Result<Option<MerRecord>, TrainError> {
    let p = root.join(MER_RECORD_FILE);
    if !p.exists() {
        return Ok(None);
    }
    let bytes = std::fs::read(&p).map_err(|e| TrainError::io(&p, e))?;
    serde_json::from_slice(&bytes)
        .map(Some)
        .map_err(|e| TrainError::Parse {
            path: p.display().to_string(),
            reason: e.to_string(),
        })
}
