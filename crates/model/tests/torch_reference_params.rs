//! `scripts/torch_reference.py` (the PyTorch eager reference of issue 9, timed side by side with
//! `depthsense bench model`) builds the same networks as `DepthNet`: for every preset its
//! trainable parameters and conv multiply-adds at 350x800 equal ours exactly. The script counts
//! on PyTorch's meta device (nothing allocated); we build each preset on the CPU. Skips when the
//! workspace `.venv` (torch) is absent or torch does not import (exit code 77).

use std::path::{Path, PathBuf};
use std::process::Command;

use depthsense_model::{report, DepthNet, ModelConfig};
use tch::{nn, Device};

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn python() -> Option<PathBuf> {
    let py = workspace().join(".venv/bin/python");
    py.exists().then_some(py)
}

const PRESETS: [&str; 3] = ["released", "paper", "tiny"];

/// (preset, params, macs_per_image) from the Python reference (one process for all presets), or
/// None (skip) without torch.
fn torch_counts(py: &Path) -> Option<Vec<(String, i64, u64)>> {
    let script = workspace().join("scripts/torch_reference.py");
    let out = Command::new(py)
        .arg(&script)
        .args([
            "--params-only",
            "--threads",
            "1",
            "--preset",
            &PRESETS.join(","),
        ])
        .output()
        .expect("running scripts/torch_reference.py");
    if out.status.code() == Some(77) {
        eprintln!(
            "SKIP: torch is not importable in .venv: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        return None;
    }
    assert!(
        out.status.success(),
        "torch_reference.py --params-only failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&out.stdout)));
    let runs = v["runs"].as_array().expect("{\"runs\": [...]}");
    Some(
        runs.iter()
            .map(|r| {
                assert_eq!(
                    (r["height"].as_i64(), r["width"].as_i64()),
                    (Some(350), Some(800))
                );
                (
                    r["config"].as_str().expect("config").to_string(),
                    r["params"].as_i64().expect("params"),
                    r["macs_per_image"].as_u64().expect("macs_per_image"),
                )
            })
            .collect(),
    )
}

#[test]
fn torch_reference_builds_our_presets_parameter_for_parameter() {
    let Some(py) = python() else {
        eprintln!("SKIP: no .venv/bin/python in the workspace (run `make setup`)");
        return;
    };
    let Some(counts) = torch_counts(&py) else {
        return;
    };
    let names: Vec<&str> = counts.iter().map(|c| c.0.as_str()).collect();
    assert_eq!(names, PRESETS, "one row per preset, in order");
    for (preset, params, macs) in counts {
        let preset = preset.as_str();
        let cfg = ModelConfig::preset(preset).unwrap();
        let vs = nn::VarStore::new(Device::Cpu);
        let net = DepthNet::new(&vs.root(), &cfg).unwrap();
        let rep = report::model_report(&vs, &net, 350, 800);
        eprintln!(
            "{preset}: ours {} params {} MACs, PyTorch {params} params {macs} MACs",
            rep.total_params, rep.total_macs
        );
        assert_eq!(
            rep.total_params, params,
            "{preset}: parameters, ours vs PyTorch"
        );
        assert_eq!(
            rep.total_macs, macs,
            "{preset}: multiply-adds per image, ours vs PyTorch"
        );
        if preset == "released" {
            assert_eq!(params, 68_399_904, "SPEC §6.1");
        }
    }
}
