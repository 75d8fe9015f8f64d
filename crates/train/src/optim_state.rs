//! What the hand-written optimisers ([`crate::sgd::Sgd`], [`crate::adam::Adam`]) share:
//! the VarStore's trainable variables in name order, zeroing their gradients, and their state
//! written to / read from safetensors atomically (an exact `--resume` needs it; tch's
//! `nn::Optimizer` cannot save its buffers).

use std::collections::BTreeMap;
use std::path::Path;

use tch::{nn::VarStore, Device, Tensor};

use depthsense_infer::NetError;

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
pub(crate) fn write_atomic(path: &Path, named: Vec<(String, Tensor)>) -> Result<(), NetError> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| NetError::io(parent, e))?;
    }
    let named: Vec<(String, Tensor)> = named
        .into_iter()
        .map(|(k, t)| (k, t.to_device(Device::Cpu)))
        .collect();
    let tmp = depthsense_base::fsutil::temp_sibling(path);
    Tensor::write_safetensors(&named, &tmp).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        NetError::TensorFile {
            path: path.to_path_buf(),
            source: e,
        }
    })?;
    depthsense_base::fsutil::sync_and_rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        NetError::io(path, e)
    })
}

/// Reads an optimiser state written by [`write_atomic`].
pub(crate) fn read(path: &Path) -> Result<Vec<(String, Tensor)>, NetError> {
    Tensor::read_safetensors(path).map_err(|source| NetError::TensorFile {
        path: path.to_path_buf(),
        source,
    })
}

/// The error for a state file that does not fit the network.
pub(crate) fn bad_state(path: &Path, reason: String) -> NetError {
    NetError::Parse {
        path: path.to_path_buf(),
        reason,
    }
}

/// The previous optimiser state beside `path` (`last.optim.safetensors` →
/// `last.optim.prev.safetensors`): the state of the checkpoint on disk while a new pair is
/// being written.
pub(crate) fn prev_path(path: &Path) -> std::path::PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let stem = name.strip_suffix(".safetensors").unwrap_or(&name);
    path.with_file_name(format!("{stem}.prev.safetensors"))
}

/// Before a checkpoint writes a new optimiser state to `path` and then the model checkpoint:
/// the state on disk moves to [`prev_path`] when it belongs to the checkpoint on disk
/// (`matches_checkpoint`), and is dropped when it does not (a kill left it newer than the
/// checkpoint; `prev` then already holds the matching one). A kill anywhere in between leaves
/// `path` or `prev` matching the checkpoint, which [`load_matching`] finds.
pub fn rotate(path: &Path, matches_checkpoint: bool) -> Result<(), NetError> {
    if !path.exists() {
        return Ok(());
    }
    if matches_checkpoint {
        let prev = prev_path(path);
        std::fs::rename(path, &prev).map_err(|e| NetError::io(&prev, e))
    } else {
        std::fs::remove_file(path).map_err(|e| NetError::io(path, e))
    }
}

/// Resume: load (with `load`, which returns the stored iteration) the optimiser state whose
/// iteration is the checkpoint's — `path`, else its [`prev_path`] sibling. Returns whether
/// `path` itself matched (the next [`rotate`] needs to know).
pub fn load_matching(
    path: &Path,
    checkpoint: &Path,
    iteration: u64,
    mut load: impl FnMut(&Path) -> Result<u64, NetError>,
) -> Result<bool, NetError> {
    let main = if path.exists() {
        Some(load(path)?)
    } else {
        None
    };
    if main == Some(iteration) {
        return Ok(true);
    }
    let prev = prev_path(path);
    let older = if prev.exists() {
        Some(load(&prev)?)
    } else {
        None
    };
    if older == Some(iteration) {
        return Ok(false);
    }
    Err(NetError::NoMatchingOptimiserState {
        state: path.to_path_buf(),
        state_at: main,
        previous: prev,
        previous_at: older,
        checkpoint: checkpoint.to_path_buf(),
        iteration,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prev_sibling_and_rotation() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("last.optim.safetensors");
        assert_eq!(prev_path(&p), d.path().join("last.optim.prev.safetensors"));
        assert_eq!(
            prev_path(Path::new(depthsense_dataset::outputs::LAST_OPTIM)),
            Path::new(depthsense_dataset::outputs::PREV_OPTIM)
        );
        rotate(&p, true).unwrap(); // nothing there yet
        std::fs::write(&p, "9").unwrap();
        rotate(&p, true).unwrap();
        assert!(!p.exists());
        assert_eq!(std::fs::read_to_string(prev_path(&p)).unwrap(), "9");
        std::fs::write(&p, "10").unwrap();
        rotate(&p, false).unwrap(); // stale: dropped, prev kept
        assert!(!p.exists());
        assert_eq!(std::fs::read_to_string(prev_path(&p)).unwrap(), "9");
    }

    #[test]
    fn the_state_of_the_checkpoint_is_found_after_a_kill_anywhere() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("last.optim.safetensors");
        let ck = d.path().join("last.safetensors");
        let read = |q: &Path| -> Result<u64, NetError> {
            Ok(std::fs::read_to_string(q).unwrap().parse().unwrap())
        };
        // killed after the rotation: only prev, at the checkpoint's iteration
        std::fs::write(prev_path(&p), "9").unwrap();
        assert!(!load_matching(&p, &ck, 9, read).unwrap());
        // killed after the new optimiser state, before the checkpoint
        std::fs::write(&p, "10").unwrap();
        assert!(!load_matching(&p, &ck, 9, read).unwrap());
        // a consistent pair
        assert!(load_matching(&p, &ck, 10, read).unwrap());
        // neither fits: an error naming all three
        let e = load_matching(&p, &ck, 11, read).unwrap_err();
        let text = e.to_string();
        assert!(
            matches!(
                e,
                NetError::NoMatchingOptimiserState {
                    state_at: Some(10),
                    previous_at: Some(9),
                    iteration: 11,
                    ..
                }
            ),
            "{text}"
        );
        assert_eq!(
            text,
            format!(
                "data: {} is at iteration 10 and {} at iteration 9, but {} is at iteration 11: \
                 no optimiser state belongs to the checkpoint",
                p.display(),
                prev_path(&p).display(),
                ck.display()
            )
        );
    }
}
