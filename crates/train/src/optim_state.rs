//! What the hand-written optimisers ([`crate::sgd::Sgd`], [`crate::mer::adam::Adam`]) share:
//! the VarStore's trainable variables in name order, zeroing their gradients, and their state
//! written to / read from safetensors atomically (an exact `--resume` needs it; tch's
//! `nn::Optimizer` cannot save its buffers).

use std::collections::BTreeMap;
use std::path::Path;

use tch::{nn::VarStore, Device, Tensor};

use crate::error::TrainError;

/// Named trainable variables of a VarStore, sorted by name.
pub(crate) struct Trainable {
    pub(crate) vars: Vec<(String, Tensor)>,
}

impl Trainable {
    pub(crate) fn new(vs: &VarStore) -> Self {
        let mut vars: Vec<(String, Tensor)> = vs
            .variables()
            .into_iter()
            .filter(|(_, t)| t.requires_grad())
            .collect();
        vars.sort_by(|a, b| a.0.cmp(&b.0));
        Self { vars }
    }

    pub(crate) fn zero_grad(&mut self) {
        for (_, v) in self.vars.iter_mut() {
            v.zero_grad();
        }
    }

    /// The device of the variables (CPU when there are none).
    pub(crate) fn device(&self) -> Device {
        self.vars.first().map_or(Device::Cpu, |(_, v)| v.device())
    }

    /// Variable name → its size, to check a loaded buffer against.
    pub(crate) fn sizes(&self) -> BTreeMap<&str, Vec<i64>> {
        self.vars
            .iter()
            .map(|(n, t)| (n.as_str(), t.size()))
            .collect()
    }
}

/// Writes `named` (moved to the CPU) as safetensors at `path`, through a temporary sibling.
pub(crate) fn write_atomic(path: &Path, named: Vec<(String, Tensor)>) -> Result<(), TrainError> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| TrainError::io(parent, e))?;
    }
    let named: Vec<(String, Tensor)> = named
        .into_iter()
        .map(|(k, t)| (k, t.to_device(Device::Cpu)))
        .collect();
    let tmp = depthsense_nuscenes::fsutil::temp_sibling(path);
    Tensor::write_safetensors(&named, &tmp).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        TrainError::Other(format!("{}: {e}", path.display()))
    })?;
    std::fs::rename(&tmp, path).map_err(|e| TrainError::io(path, e))
}

/// Reads an optimiser state written by [`write_atomic`].
pub(crate) fn read(path: &Path) -> Result<Vec<(String, Tensor)>, TrainError> {
    Tensor::read_safetensors(path)
        .map_err(|e| TrainError::Other(format!("{}: {e}", path.display())))
}

/// The error for a state file that does not fit the network.
pub(crate) fn bad_state(path: &Path, reason: String) -> TrainError {
    TrainError::Parse {
        path: path.display().to_string(),
        reason,
    }
}
