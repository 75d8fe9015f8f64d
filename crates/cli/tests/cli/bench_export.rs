//! `depthsense bench export`: one run times onnxruntime and depthsense on the same inputs and
//! the two depth maps agree (the export tests' tolerance: 1 mm on ≥ 99.9 % of the pixels).

use std::process::Command;

#[test]
fn bench_export_times_both_engines_on_the_same_inputs() {
    let Some(python) = depthsense_testkit::python_with(
        &["torch", "numpy", "onnx", "onnxruntime"],
        depthsense_testkit::REQUIRE_TORCH,
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("bench-export.json");
    let o = Command::new(env!("CARGO_BIN_EXE_depthsense"))
        .args([
            "bench",
            "export",
            "--config",
            "tiny",
            "--warmup-runs",
            "0",
            "--repeats",
            "2",
        ])
        .arg("--python")
        .arg(&python)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    assert_eq!(r["config"], "tiny");
    assert_eq!(
        (r["height"].as_u64(), r["width"].as_u64()),
        (Some(350), Some(800))
    );
    for engine in ["depthsense", "folded", "onnxruntime"] {
        let ms = r[engine]["median_ms"].as_f64().unwrap();
        assert!(ms > 0.0 && ms.is_finite(), "{engine}: {ms}");
    }
    assert_eq!(r["onnxruntime_providers"][0], "CPUExecutionProvider");
    let same = r["folded_frac_same_depth"].as_f64().unwrap();
    assert!(same >= 0.9999, "the inference graph's bins: {same}");
    let folded_within = r["folded_frac_within_1mm"].as_f64().unwrap();
    assert!(
        folded_within >= 0.999,
        "the inference graph against onnxruntime: {folded_within}"
    );
    let within = r["frac_within_1mm"].as_f64().unwrap();
    assert!(within >= 0.999, "{within}");
    assert!(r["onnx_bytes"].as_u64().unwrap() > 1_000_000);
    assert_eq!(r["params"].as_u64(), Some(923_563), "the tiny preset");
}
