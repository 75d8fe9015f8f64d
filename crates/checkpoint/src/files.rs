//! The network's files on disk: the atomic write with a [`ModelError`] naming the file, and
//! the refusal of a missing checkpoint that lists the ones beside it.

use std::path::Path;

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

/// `path` exists; otherwise an error that says what the flag takes (`what`) and lists the
/// checkpoints in the folder it names, if any.
pub fn require_file(path: &Path, what: &str) -> Result<(), ModelError> {
    if path.exists() {
        return Ok(());
    }
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let mut near: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .map(|e| e.path())
                .filter(|p| {
                    p.extension()
                        .is_some_and(|x| x == "safetensors" || x == "pth" || x == "pt")
                })
                .map(|p| p.display().to_string())
                .collect()
        })
        .unwrap_or_default();
    near.sort();
    let beside = if near.is_empty() {
        String::new()
    } else {
        format!("; checkpoints in {}: {}", dir.display(), near.join(", "))
    };
    Err(ModelError::format(
        path,
        format!("no such file ({what}){beside}"),
    ))
}
