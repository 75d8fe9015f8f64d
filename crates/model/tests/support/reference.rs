//! Running `released_reference.py` (the authors' network in plain PyTorch) from a test; shared
//! by `crates/model/tests/released_reference.rs` and
//! `crates/train/tests/released_real_keyframe.rs` (included there by path).

use std::path::{Path, PathBuf};
use std::process::Command;

/// The workspace's `.venv` Python with torch: a failure under DEPTHSENSE_REQUIRE_TORCH=1, else a
/// counted skip.
pub fn python() -> Option<PathBuf> {
    depthsense_testkit::python_with_torch()
}

/// Writes the script into `dir` and runs it with `params` (JSON); it leaves `weights.pth`,
/// `keys.json`, the inputs and its decoded levels / depth in `dir` and prints a JSON summary,
/// returned here. `None` (with a SKIP line) when there is no `.venv` or torch cannot be
/// imported; a failing script fails the test.
pub fn run_reference(dir: &Path, params: &serde_json::Value) -> Option<serde_json::Value> {
    let py = python()?;
    let script = dir.join("released_reference.py");
    std::fs::write(&script, include_str!("../released_reference.py")).unwrap();
    let out = Command::new(&py)
        .arg(&script)
        .arg(dir)
        .arg(params.to_string())
        .output()
        .unwrap();
    if out.status.code() == Some(77) {
        let why = format!("{}: {}", py.display(), String::from_utf8_lossy(&out.stderr));
        return depthsense_testkit::unavailable(depthsense_testkit::REQUIRE_TORCH, &why);
    }
    assert!(
        out.status.success(),
        "reference script failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    eprintln!("PyTorch reference: {info}");
    assert!(
        info["distinct_levels"].as_i64().unwrap() >= 5,
        "reference too uniform to test: {info}"
    );
    Some(info)
}
