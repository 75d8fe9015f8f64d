//! `depthsense bench export`: onnxruntime's latency on an exported graph, measured in the
//! project's Python (`make setup` installs onnxruntime) on inputs depthsense gives it, so the
//! command can time depthsense's own forward on the same inputs in the same run and compare the
//! two depth maps.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde::{Deserialize, Serialize};

use crate::python::{find_python, PYTHON_ENV};
use crate::ExportError;

/// Times `session.run` (after warm-up) and writes the last output; reads the inputs as raw
/// float32 files. Exit code 77 when onnxruntime or numpy is missing.
const ORT_BENCH_PY: &str = r#"
import json, sys, time
try:
    import numpy as np
    import onnxruntime as ort
except ImportError as e:
    print(f"missing package: {e}", file=sys.stderr); sys.exit(77)
a = json.loads(sys.argv[1])
so = ort.SessionOptions()
so.intra_op_num_threads = a["threads"]
so.inter_op_num_threads = 1
sess = ort.InferenceSession(a["onnx"], so, providers=[a["provider"]])
feeds = {}
for name, path, shape in a["inputs"]:
    feeds[name] = np.fromfile(path, dtype=np.float32).reshape(shape)
for _ in range(a["warmup"]):
    out = sess.run(["depth"], feeds)[0]
ms = []
for _ in range(max(1, a["repeats"])):
    t = time.perf_counter()
    out = sess.run(["depth"], feeds)[0]
    ms.append((time.perf_counter() - t) * 1e3)
np.ascontiguousarray(out, dtype=np.float32).tofile(a["depth_out"])
print(json.dumps({"ms": ms, "onnxruntime": ort.__version__, "providers": sess.get_providers()}))
"#;

/// One input of the graph: its name, values and shape.
pub struct GraphInput<'a> {
    pub name: &'a str,
    pub values: &'a [f32],
    pub shape: Vec<usize>,
}

/// What onnxruntime measured.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct OrtTiming {
    pub onnxruntime_version: String,
    pub providers: Vec<String>,
    pub threads: usize,
    /// Milliseconds of each timed run.
    pub ms: Vec<f64>,
    /// The `depth` output of the last run, row-major.
    #[serde(skip)]
    pub depth_m: Vec<f32>,
}

#[derive(Deserialize)]
struct Reply {
    ms: Vec<f64>,
    onnxruntime: String,
    providers: Vec<String>,
}

/// Runs `onnx` in onnxruntime with `provider` (e.g. `CPUExecutionProvider`) on `inputs`,
/// `warmup` untimed then `repeats` timed runs, `threads` intra-op threads.
pub fn time_onnxruntime(
    python: Option<&Path>,
    onnx: &Path,
    inputs: &[GraphInput<'_>],
    provider: &str,
    threads: usize,
    warmup: usize,
    repeats: usize,
) -> Result<OrtTiming, ExportError> {
    let python: PathBuf = python.map(Path::to_path_buf).unwrap_or_else(find_python);
    let failed = |detail: String| ExportError::Python {
        python: python.display().to_string(),
        out: onnx.display().to_string(),
        detail,
    };
    let work = tempfile::tempdir().map_err(|e| ExportError::io(&std::env::temp_dir(), e))?;
    let mut specs = vec![];
    for i in inputs {
        let p = work.path().join(format!("{}.f32", i.name));
        let bytes: Vec<u8> = i.values.iter().flat_map(|v| v.to_le_bytes()).collect();
        std::fs::write(&p, bytes).map_err(|e| ExportError::io(&p, e))?;
        specs.push(serde_json::json!([i.name, p, i.shape]));
    }
    let depth_out = work.path().join("depth.f32");
    let args = serde_json::json!({
        "onnx": onnx, "inputs": specs, "provider": provider, "threads": threads,
        "warmup": warmup, "repeats": repeats, "depth_out": depth_out,
    });
    let output = Command::new(&python)
        .args(["-c", ORT_BENCH_PY, &args.to_string()])
        .output()
        .map_err(|e| failed(format!("cannot start it ({e}); set {PYTHON_ENV}")))?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        let last = stderr.trim_end().lines().last().unwrap_or("").to_string();
        return Err(failed(match output.status.code() {
            Some(77) => format!("{last} (`make setup` installs onnxruntime into .venv)"),
            c => format!("onnxruntime failed ({c:?}): {last}"),
        }));
    }
    let reply: Reply = serde_json::from_slice(&output.stdout)
        .map_err(|e| failed(format!("unreadable timing reply: {e}")))?;
    let bytes = std::fs::read(&depth_out).map_err(|e| ExportError::io(&depth_out, e))?;
    let depth_m: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok(OrtTiming {
        onnxruntime_version: reply.onnxruntime,
        providers: reply.providers,
        threads,
        ms: reply.ms,
        depth_m,
    })
}
