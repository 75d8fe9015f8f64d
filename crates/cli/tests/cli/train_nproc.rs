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

/// SIGTERM to the launcher of `train --nproc 2`: it passes the signal on once, the ranks agree
/// on one iteration, rank 0 checkpoints and prints the line with the launcher's command
/// (`--nproc 2` included), every process exits with 143, and `--resume` finishes the run.
#[test]
fn a_sigterm_to_the_launcher_stops_every_rank_at_one_checkpoint() {
    use std::time::{Duration, Instant};
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let out = tmp.path().join("run");
    depthsense_data::write_toy_dataset(&data, 6, 4, 128, 64, 5).unwrap();
    let train = || {
        // Batch 2: one sample per rank.
        let mut c = crate::common::tiny_train(&data, &out, 4);
        c.args(["--nproc", "2", "--dist-timeout", "120"]);
        c
    };
    let log = tmp.path().join("term.log");
    let mut c = train();
    c.stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap());
    let mut g = crate::common::Guard::new(c.spawn().unwrap());
    let iters = || {
        std::fs::read_to_string(out.join("metrics.jsonl"))
            .map_or(0, |t| t.matches("\"kind\":\"iter\"").count())
    };
    let t = Instant::now();
    while iters() < 3 {
        let log_text = || std::fs::read_to_string(&log).unwrap_or_default();
        assert!(!g.ended(), "finished before the signal:\n{}", log_text());
        assert!(t.elapsed() < Duration::from_secs(180), "too slow to start");
        std::thread::sleep(Duration::from_millis(5));
    }
    // SAFETY: kill(2) of our own running child (the launcher).
    unsafe { libc::kill(g.child().id() as libc::pid_t, libc::SIGTERM) };
    let status = g.wait(Duration::from_secs(180));
    let err = std::fs::read_to_string(&log).unwrap();
    assert_eq!(status.code(), Some(143), "{err}");
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("interrupted at iteration "))
        .collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(
        lines[0].contains("--nproc 2") && lines[0].ends_with(" --resume"),
        "{}",
        lines[0]
    );
    let stopped_at = iters();
    assert!(stopped_at < 32, "{err}");
    let mut c = train();
    c.arg("--resume");
    let o = c.output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert_eq!(iters(), 32, "{err}");
}
