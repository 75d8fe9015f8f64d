//! The network's files on disk: the atomic write with a [`ModelError`] naming the file, and
//! the refusal of a missing checkpoint that lists the ones beside it.

use std::path::{Path, PathBuf};

use depthsense_model::ModelError;

/// Writes `bytes` to `path` atomically: the workspace's one atomic write
/// (`depthsense_base::fsutil::write_atomic`: temporary sibling, fsync, rename), with the
/// error as a [`ModelError`] naming `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), ModelError> {
    // The folder first, so that its failure names the folder (as before).
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| ModelError::io(dir, e))?;
    depthsense_base::fsutil::write_atomic(path, bytes).map_err(|e| ModelError::io(path, e))
}

/// The checkpoint `path` names: the file itself, or a run folder's `best.safetensors` (said on
/// stderr). Otherwise an error that says what the flag takes (`what`) and lists the checkpoints
/// in the folder it names, if any.
pub fn require_file(path: &Path, what: &str) -> Result<PathBuf, ModelError> {
    if path.is_dir() {
        let best = path.join(BEST);
        if best.is_file() {
            // Said once, however often the path is resolved (config, then weights).
            static SAID: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
            if !SAID.swap(true, std::sync::atomic::Ordering::Relaxed) {
                eprintln!(
                    "{}: a run folder; using its {BEST} (the weights of its best validation)",
                    path.display()
                );
            }
            return Ok(best);
        }
        return Err(ModelError::format(
            path,
            format!("a folder without {BEST} ({what}){}", beside(path)),
        ));
    }
    if path.exists() {
        return Ok(path.to_path_buf());
    }
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    Err(ModelError::format(
        path,
        format!("no such file ({what}){}", beside(dir)),
    ))
}

/// The file name of a run's best checkpoint (`depthsense_dataset::outputs::BEST_CKPT`).
const BEST: &str = "best.safetensors";

/// `; checkpoints in DIR: …` for the loadable checkpoints in `dir` (not the optimiser states
/// beside them), or nothing.
fn beside(dir: &Path) -> String {
    let mut near: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .map(|e| e.path())
                .filter(|p| is_checkpoint_name(p))
                .map(|p| p.display().to_string())
                .collect()
        })
        .unwrap_or_default();
    near.sort();
    if near.is_empty() {
        String::new()
    } else {
        format!("; checkpoints in {}: {}", dir.display(), near.join(", "))
    }
}

/// A name a loadable checkpoint has: `.safetensors` (but not a run's optimiser state,
/// `*.optim.safetensors` / `*.optim.prev.safetensors`), `.pth`, `.pt`.
fn is_checkpoint_name(p: &Path) -> bool {
    let name = p
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    let optim = name.contains(".optim.");
    let ext = p
        .extension()
        .is_some_and(|x| x == "safetensors" || x == "pth" || x == "pt");
    ext && !optim
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_folder_means_its_best_and_optimiser_states_are_not_checkpoints() {
        let d = tempfile::tempdir().unwrap();
        for f in [
            "best.safetensors",
            "last.safetensors",
            "last.optim.safetensors",
        ] {
            std::fs::write(d.path().join(f), b"x").unwrap();
        }
        std::fs::write(d.path().join("last.optim.prev.safetensors"), b"x").unwrap();
        assert_eq!(
            require_file(d.path(), "--checkpoint").unwrap(),
            d.path().join("best.safetensors")
        );
        let e = require_file(&d.path().join("nope.safetensors"), "--checkpoint")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("best.safetensors") && e.contains("last.safetensors"),
            "{e}"
        );
        assert!(!e.contains("optim"), "{e}");
        std::fs::remove_file(d.path().join("best.safetensors")).unwrap();
        let e = require_file(d.path(), "--checkpoint")
            .unwrap_err()
            .to_string();
        assert!(e.contains("a folder without best.safetensors"), "{e}");
    }
}
