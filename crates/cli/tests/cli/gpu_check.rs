//! `scripts/gpu-check.sh --cpu-dry-run` (issues 9 and 45): the whole GPU script on the CPU with
//! the debug binary — the science step on a tiny world (four runs at once, gathered), the bf16
//! check on its trained checkpoint, one Gloo rank against one process, onnxruntime on the
//! trained graph, the benchmarks, training and the demo — so that nothing that can fail on a
//! GPU machine is first seen there. science.json has the keys it has on the GPU.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// science.json's keys, the same on the GPU (scripts/science_json.py).
const SCIENCE_KEYS: [&str; 21] = [
    "arms",
    "budget_s",
    "checkpoint_for_bf16",
    "date_utc",
    "device",
    "dry_run",
    "frame",
    "machine",
    "margin",
    "mer",
    "ok",
    "plan",
    "preset",
    "runs",
    "runs_from",
    "schema",
    "stages",
    "training",
    "trend",
    "wall_seconds",
    "world",
];

const MARGIN_KEYS: [&str; 10] = [
    "beyond_seed_spread",
    "finding",
    "margin_m",
    "margin_pct",
    "margin_se_m",
    "margin_se_pct",
    "paired",
    "seed_spread_m",
    "t",
    "verdict",
];

fn json(p: &Path) -> serde_json::Value {
    let text = std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    serde_json::from_slice(&text).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn keys(v: &serde_json::Value) -> Vec<&str> {
    let mut k: Vec<&str> = v.as_object().unwrap().keys().map(String::as_str).collect();
    k.sort_unstable();
    k
}

/// Runs the script in its own process group; the whole group is killed past `limit`.
fn run_dry(out: &Path, python: &Path, limit: Duration) -> (bool, String) {
    use std::os::unix::process::CommandExt;
    let root = depthsense_testkit::workspace_root();
    let log = out.with_extension("log");
    let mut child = Command::new("bash")
        .arg(root.join("scripts/gpu-check.sh"))
        .args(["--cpu-dry-run", "--out"])
        .arg(out)
        .env("DEPTHSENSE_BIN", env!("CARGO_BIN_EXE_depthsense"))
        .env("PYTHON", python)
        .stdout(Stdio::from(std::fs::File::create(&log).unwrap()))
        .stderr(Stdio::from(
            std::fs::File::create(log.with_extension("err")).unwrap(),
        ))
        .process_group(0)
        .spawn()
        .unwrap();
    let t = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t.elapsed() > limit {
            let _ = Command::new("kill")
                .args(["-KILL", "--", &format!("-{}", child.id())])
                .status();
            let _ = child.wait();
            panic!("gpu-check.sh --cpu-dry-run did not finish within {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let text = std::fs::read_to_string(&log).unwrap_or_default()
        + &std::fs::read_to_string(log.with_extension("err")).unwrap_or_default();
    (status.success(), text)
}

#[test]
fn the_gpu_script_runs_dry_on_the_cpu_with_the_science_first() {
    let Some(python) = depthsense_testkit::python_with(
        &["torch", "numpy", "onnx", "onnxruntime"],
        depthsense_testkit::REQUIRE_TORCH,
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let (ok, text) = run_dry(&out, &python, Duration::from_secs(900));
    assert!(ok, "{text}");
    let mut files: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    files.sort();
    assert_eq!(
        files,
        [
            "bench_ours.json",
            "bench_torch.json",
            "demo.json",
            "env.json",
            "log.txt",
            "science.json",
            "summary.json",
            "train.json"
        ],
        "at most 8 files come back from a device run"
    );

    let sci = json(&out.join("science.json"));
    assert_eq!(keys(&sci), SCIENCE_KEYS, "science.json's keys");
    assert_eq!(keys(&sci["margin"]), MARGIN_KEYS);
    assert_eq!(sci["schema"], "depthsense-science/1");
    assert_eq!(sci["dry_run"], true);
    assert_eq!(sci["ok"], true, "{}\n{text}", sci["stages"]);
    assert_eq!(
        sci["plan"]["mode"], "parallel",
        "the dry run takes the path with more to go wrong"
    );
    for split in ["train", "val", "test"] {
        let c = &sci["world"]["splits"][split]["conditions"];
        for cond in ["day", "night", "rain"] {
            assert!(
                c[cond].as_u64().unwrap_or(0) > 0,
                "{split} has no {cond}: {c}"
            );
        }
    }
    let runs = sci["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 4, "rgb and late-sam, two seeds each");
    for r in runs {
        let rmse = r["test_rmse_m"].as_f64().unwrap();
        assert!(rmse.is_finite() && rmse > 0.0, "{r}");
        assert_eq!(
            r["test_images"].as_u64(),
            sci["training"]["test_samples"].as_u64(),
            "every test keyframe"
        );
    }
    let paired = &sci["margin"]["paired"];
    assert_eq!(paired["n"], 2, "paired over the two seeds");
    assert!(sci["margin"]["margin_m"]["mean"].as_f64().is_some());
    let iterations = sci["training"]["iterations"].as_u64().unwrap();
    assert!(iterations >= 1);
    assert!(Path::new(sci["checkpoint_for_bf16"].as_str().unwrap())
        .ends_with("late-sam/seed0/best.safetensors"));

    let summary = json(&out.join("summary.json"));
    let steps = summary["steps"].as_object().unwrap();
    let not_ok: Vec<_> = steps.iter().filter(|(_, v)| *v != "ok").collect();
    assert!(not_ok.is_empty(), "steps not ok: {not_ok:?}\n{text}");
    let env = json(&out.join("env.json"));
    let first = &env["steps"][0]["step"];
    assert_eq!(first, "science", "the science runs first");
    let checks = &summary["checks"];
    let nccl = &checks["nccl"];
    assert!(nccl["iterations_compared"].as_u64().unwrap() >= 1, "{nccl}");
    assert_eq!(
        nccl["equal_within_1e-4"], true,
        "one rank = one process: {nccl}"
    );
    assert_eq!(nccl["backend"], "gloo", "on the CPU; NCCL on CUDA");
    assert!(checks["ort_cuda"]["median_ms"].as_f64().unwrap() > 0.0);
    assert_eq!(
        checks["deprecation_lines"], 0,
        "{}",
        checks["deprecation_examples"]
    );
    assert_eq!(
        checks["bf16_trained_weights"], "trained",
        "the bf16 check runs on the science step's checkpoint"
    );
    let inference = &checks["inference_speed"];
    let tiny = &inference["inference_graph"]["tiny"];
    assert_eq!(tiny["graph"], "inference");
    assert!(tiny["forward_decode_cuda_graph_ms"].as_f64().unwrap() > 0.0);
    assert!(
        tiny["forward_decode_channels_last_ms"].as_f64().unwrap() > 0.0,
        "the channels-last inference row: {tiny}"
    );
    assert!(
        tiny["cuda_graph"]
            .as_str()
            .unwrap()
            .contains("not on a CUDA device"),
        "on the CPU the graph row runs eagerly and says why: {tiny}"
    );
    let line = inference["predict_pipeline"].as_str().unwrap_or_default();
    assert!(
        line.contains("images/s"),
        "predict's pipeline line: {inference}"
    );
    let tokens = inference["predict_tokens"].as_str().unwrap_or_default();
    assert!(
        tokens.contains("10 images") && tokens.contains("images/s"),
        "predict over a token list: {inference}"
    );
    let how = inference["predict_cuda_graph_how"]
        .as_str()
        .unwrap_or_default();
    assert!(
        how.contains("not on a CUDA device"),
        "predict --cuda-graph on the CPU: {inference}"
    );
    assert!(
        inference["profile_train"]["layouts"]["nchw"]["top"][0]["self_ms_per_step"]
            .as_f64()
            .unwrap()
            > 0.0
    );
}
