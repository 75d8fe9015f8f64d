//! `depthsense train --nproc 2`: the launcher starts two workers with torchrun's environment;
//! only rank 0 writes RUN/ and prints the summary.

use std::process::Command;

#[test]
fn nproc_two_trains_with_sync_bn_and_rank_zero_writes_the_run() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let out = tmp.path().join("run");
    depthsense_data::write_toy_dataset(&data, 5, 4, 128, 64, 11).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_depthsense"))
        .args(["train", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(&out)
        .args([
            "--config",
            "tiny",
            "--epochs",
            "1",
            "--batch-size",
            "4",
            "--dropout",
            "0",
            "--no-augment",
            "--device",
            "cpu",
            "--jobs",
            "1",
            "--max-val-samples",
            "2",
            "--nproc",
            "2",
            "--sync-bn",
            "--check-replicas",
            "--dist-timeout",
            "120",
        ])
        .env_remove("WORLD_SIZE")
        .env_remove("RANK")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert_eq!(err.matches("run directory:").count(), 1, "{err}");
    let metrics = std::fs::read_to_string(out.join("metrics.jsonl")).unwrap();
    assert_eq!(metrics.matches("\"iter\"").count(), 3, "{metrics}");
    assert!(out.join("last.safetensors").exists());
    // a batch that the ranks cannot share is refused
    let o = Command::new(env!("CARGO_BIN_EXE_depthsense"))
        .args(["train", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(tmp.path().join("bad"))
        .args([
            "--config",
            "tiny",
            "--epochs",
            "1",
            "--batch-size",
            "3",
            "--device",
            "cpu",
            "--nproc",
            "2",
            "--dist-timeout",
            "60",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("not a multiple of the 2 ranks"), "{err}");
}
