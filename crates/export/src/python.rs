//! The conversion in Python: `python/depthsense_torch.py` and `python/depthsense_export.py`
//! travel inside the binary and are written to a temporary folder, so an exported model needs
//! only a Python with torch (and onnx for ONNX's check) — not the source tree.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::{ExportError, ExportOptions, Format};

/// `python/depthsense_torch.py`, as built into this binary.
pub const DEPTHSENSE_TORCH_PY: &str = include_str!("../../../python/depthsense_torch.py");
/// `python/depthsense_export.py`, as built into this binary.
pub const DEPTHSENSE_EXPORT_PY: &str = include_str!("../../../python/depthsense_export.py");

/// Environment variable naming the Python that runs the conversion.
pub const PYTHON_ENV: &str = "DEPTHSENSE_PYTHON";

/// The Python for the conversion: `$DEPTHSENSE_PYTHON`; else the active virtual environment's
/// (`$VIRTUAL_ENV/bin/python`); else the `.venv` of the checkout this binary was built in (what
/// `make setup` installs: torch, onnx, onnxruntime); else `python3` on the PATH.
pub fn find_python() -> PathBuf {
    if let Some(p) = std::env::var_os(PYTHON_ENV) {
        return PathBuf::from(p);
    }
    if let Some(v) = std::env::var_os("VIRTUAL_ENV") {
        let p = Path::new(&v).join("bin/python");
        if p.exists() {
            return p;
        }
    }
    let built_in = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    if built_in.exists() {
        return built_in;
    }
    PathBuf::from("python3")
}

/// Runs the exporter on `weights` + `config` (in `work`), writing every `(format, file)` of
/// `targets` from one trace.
pub(crate) fn convert(
    opts: &ExportOptions,
    work: &Path,
    weights: &Path,
    config: &Path,
    targets: &[(Format, PathBuf)],
) -> Result<(), ExportError> {
    for (name, text) in [
        ("depthsense_torch.py", DEPTHSENSE_TORCH_PY),
        ("depthsense_export.py", DEPTHSENSE_EXPORT_PY),
    ] {
        let p = work.join(name);
        std::fs::write(&p, text).map_err(|e| ExportError::io(&p, e))?;
    }
    let python = opts.python.clone().unwrap_or_else(find_python);
    let outs: Vec<String> = targets
        .iter()
        .map(|(_, p)| p.display().to_string())
        .collect();
    let failed = |detail: String| ExportError::Python {
        python: python.display().to_string(),
        out: outs.join(", "),
        detail,
    };
    let mut command = Command::new(&python);
    command
        .arg(work.join("depthsense_export.py"))
        .arg("--weights")
        .arg(weights)
        .arg("--config")
        .arg(config);
    for (format, out) in targets {
        command
            .args(["--format", format.name()])
            .arg("--out")
            .arg(out);
    }
    let output = command
        .args(["--batch", &opts.batch.arg()])
        .args(["--precision", opts.precision.name()])
        .output()
        .map_err(|e| failed(format!("cannot start it ({e}); set {PYTHON_ENV}")))?;
    if output.status.success() {
        return Ok(());
    }
    let stderr = String::from_utf8_lossy(&output.stderr);
    let tail: Vec<&str> = stderr.trim_end().lines().rev().take(6).collect();
    let tail: Vec<&str> = tail.into_iter().rev().collect();
    let why = match output.status.code() {
        Some(77) => {
            "a Python package is missing (`make setup` installs torch, onnx and onnxruntime \
                     into .venv)"
                .to_string()
        }
        Some(c) => format!("exit code {c}"),
        None => "killed by a signal".to_string(),
    };
    Err(failed(format!("{why}: {}", tail.join(" | "))))
}
