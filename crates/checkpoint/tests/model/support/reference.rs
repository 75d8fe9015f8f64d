//! Running the PyTorch reference scripts from a test: `released_reference.py` (the authors'
//! network in plain PyTorch) and `torchvision_reference.py` (torchvision's ResNet key names).
//! Shared by the model crate's tests, `crates/eval/tests/eval/released_real_keyframe.rs` and
//! `crates/export/tests/export.rs` (included there by path).
// Each test binary uses a part of these helpers.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// The workspace's `.venv` Python with torch: a failure under DEPTHSENSE_REQUIRE_TORCH=1, else a
/// counted skip.
pub fn python() -> Option<PathBuf> {
    depthsense_testkit::python_with_torch()
}

/// Writes `source` into `dir/name` and runs it with `dir` and `params` (JSON); returns the JSON
/// summary it prints. `None` (a counted skip, or a failure under DEPTHSENSE_REQUIRE_TORCH=1)
/// when torch cannot be used; a failing script fails the test.
pub fn run_script(
    dir: &Path,
    name: &str,
    source: &str,
    params: &serde_json::Value,
) -> Option<serde_json::Value> {
    let py = python()?;
    let script = dir.join(name);
    std::fs::write(&script, source).unwrap();
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
        "{name} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    eprintln!("PyTorch reference ({name}): {info}");
    Some(info)
}

/// Runs `released_reference.py`: it leaves `weights.pth`, `keys.json`, the inputs and its
/// decoded levels / depth in `dir` (with `"fill": "distinct"`: the weights and keys only).
pub fn run_reference(dir: &Path, params: &serde_json::Value) -> Option<serde_json::Value> {
    let info = run_script(
        dir,
        "released_reference.py",
        include_str!("../../released_reference.py"),
        params,
    )?;
    if let Some(levels) = info.get("distinct_levels") {
        assert!(
            levels.as_i64().unwrap() >= 5,
            "reference too uniform to test: {info}"
        );
    }
    Some(info)
}

/// Runs `torchvision_reference.py` (`{"depth": 18|34|50|101, "width": w}`): `weights.pth` with
/// torchvision's key names and distinct values, and `keys.json`, in `dir`.
pub fn run_torchvision(dir: &Path, params: &serde_json::Value) -> Option<serde_json::Value> {
    run_script(
        dir,
        "torchvision_reference.py",
        include_str!("../../torchvision_reference.py"),
        params,
    )
}
