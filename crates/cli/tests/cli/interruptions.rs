//! What survives a kill or a full disk, with the real binary (docs/guide/reliability.md):
//! - `prepare` killed with SIGKILL five times, then run to the end, leaves exactly the files of
//!   one uninterrupted run (byte for byte);
//! - `train` killed with SIGKILL after a checkpoint and continued with `--resume` ends with the
//!   weights and the metrics of an uninterrupted run;
//! - a disk that fills up (simulated by a file-size limit, `ulimit -f`, under which a write fails
//!   as on a full disk, with EFBIG instead of ENOSPC) makes `prepare` and `train` fail naming
//!   the file, and leaves nothing corrupt: the last checkpoint is untouched, no temporary file
//!   stays, and the same command finishes once there is room.
//!
//! Every child is killed when a test fails and every wait has a deadline.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use crate::common;
use common::{tensors, Guard};

const BIN: &str = env!("CARGO_BIN_EXE_depthsense");

fn output(c: &mut Command) -> Output {
    c.env_remove("WORLD_SIZE")
        .env_remove("RANK")
        .output()
        .unwrap()
}

fn ok(o: &Output) {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Everything below `dir`, dot-files and folders (empty ones too) included: relative path →
/// bytes (a folder: its path with a trailing `/` and no bytes; the lock files, which record the
/// pid of their last holder: present, bytes not compared).
fn tree(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    fn walk(root: &Path, d: &Path, m: &mut BTreeMap<PathBuf, Vec<u8>>) {
        for e in std::fs::read_dir(d).unwrap() {
            let p = e.unwrap().path();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            let rel = p.strip_prefix(root).unwrap().to_path_buf();
            if p.is_dir() {
                m.insert(PathBuf::from(format!("{}/", rel.display())), vec![]);
                walk(root, &p, m);
            } else if name == ".depthsense.lock" || name == ".index.lock" {
                m.insert(rel, vec![]);
            } else {
                m.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    let mut m = BTreeMap::new();
    walk(dir, dir, &mut m);
    m
}

fn synth_world(tmp: &Path) -> PathBuf {
    let world = tmp.join("world");
    ok(&output(
        Command::new(BIN)
            .args(["synth", "--out"])
            .arg(&world)
            .args(["--scenes", "3", "--keyframes-per-scene", "3", "--seed", "5"])
            .args(["--jobs", "1"]),
    ));
    world
}

fn prepare(world: &Path, out: &Path) -> Command {
    let mut c = Command::new(BIN);
    c.args(["prepare", "--dataroot"])
        .arg(world)
        .args([
            "--version",
            "v1.0-synth",
            "--split",
            "all",
            "--lidar-sweeps",
            "1",
        ])
        .args(["--jobs", "1", "--out"])
        .arg(out);
    c
}

/// `bash -c 'ulimit -f KB; trap "" XFSZ; exec CMD…'`: writes beyond KB KiB fail with EFBIG.
fn limited(kb: u32, c: &Command) -> Command {
    let mut l = Command::new("bash");
    l.arg("-c")
        .arg(format!("ulimit -f {kb}; trap '' XFSZ; exec \"$@\""))
        .arg("limited")
        .arg(c.get_program())
        .args(c.get_args());
    l
}

#[test]
fn prepare_killed_five_times_then_finished_equals_one_clean_run() {
    let tmp = tempfile::tempdir().unwrap();
    let world = synth_world(tmp.path());
    let clean = tmp.path().join("clean");
    let t = Instant::now();
    ok(&output(&mut prepare(&world, &clean)));
    let clean_s = t.elapsed();

    let out = tmp.path().join("killed");
    let mut interrupted = 0;
    for k in 1..=5u32 {
        let mut c = prepare(&world, &out);
        c.stdout(Stdio::null()).stderr(Stdio::null());
        let mut g = Guard::new(c.spawn().unwrap());
        std::thread::sleep(clean_s.mul_f64(k as f64 / 7.0));
        if !g.ended() {
            interrupted += 1;
        }
        g.kill(); // SIGKILL
    }
    eprintln!("{interrupted} of 5 kills interrupted a running prepare (clean run {clean_s:?})");
    assert!(interrupted >= 1, "no kill landed while prepare ran");
    // The temporary folder of a prepare killed while writing a sample, whose parent has not
    // reaped it yet (a zombie: its /proc entry is still there).
    let mut zombie = Command::new("sleep").arg("60").spawn().unwrap();
    zombie.kill().unwrap();
    let t = Instant::now();
    while depthsense_prep::index::pid_alive(zombie.id()) {
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "sleep survived SIGKILL"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let stale = out.join(format!(".tmp-{}-{}", zombie.id(), "0".repeat(32)));
    std::fs::create_dir_all(&stale).unwrap();
    std::fs::write(stale.join("image.png"), b"half a sample").unwrap();
    ok(&output(&mut prepare(&world, &out)));
    zombie.wait().unwrap();
    assert!(!stale.exists(), "the stale temporary folder stayed");
    let (a, b) = (tree(&clean), tree(&out));
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "the same files"
    );
    for (p, bytes) in &a {
        assert!(b[p] == *bytes, "{} differs", p.display());
    }

    // A full disk: the samples fail naming the file; nothing half-written stays; with room,
    // the same command finishes with the clean run's files.
    let full = tmp.path().join("full");
    let o = output(&mut limited(64, &prepare(&world, &full)));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("File too large") && err.contains(".png"),
        "{err}"
    );
    ok(&output(&mut prepare(&world, &full)));
    let c = tree(&full);
    assert_eq!(c.keys().collect::<Vec<_>>(), a.keys().collect::<Vec<_>>());
    assert!(a.iter().all(|(p, bytes)| c[p] == *bytes));
}

fn toy(tmp: &Path) -> PathBuf {
    let data = tmp.join("data");
    depthsense_data::write_toy_dataset(&data, 6, 4, 128, 64, 5).unwrap();
    data
}

fn train(data: &Path, out: &Path) -> Command {
    common::tiny_train(data, out, 4)
}

/// The records of metrics.jsonl without the wall-time fields.
fn records(p: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .map(|l| {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            if let Some(m) = v.as_object_mut() {
                m.retain(|k, _| !k.ends_with("seconds") && !k.ends_with("_s"));
            }
            v
        })
        .collect()
}

#[test]
fn train_killed_after_a_checkpoint_resumes_to_the_uninterrupted_run() {
    let tmp = tempfile::tempdir().unwrap();
    let data = toy(tmp.path());
    let full = tmp.path().join("full");
    ok(&output(&mut train(&data, &full)));

    let run = tmp.path().join("killed");
    let mut c = train(&data, &run);
    c.args(["--checkpoint-every", "1"])
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    let mut g = Guard::new(c.spawn().unwrap());
    let t = Instant::now();
    // Past the first epoch's checkpoint (8 iterations per epoch), then SIGKILL.
    while records_or_empty(&run.join("metrics.jsonl")) < 11 {
        assert!(!g.ended(), "finished before it was killed");
        assert!(
            t.elapsed() < Duration::from_secs(120),
            "too slow to reach a checkpoint"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    g.kill();
    assert!(run.join("last.safetensors").exists());
    let mut c = train(&data, &run);
    c.arg("--resume");
    ok(&output(&mut c));
    for ck in ["last.safetensors", "best.safetensors"] {
        assert!(
            tensors(&full.join(ck)) == tensors(&run.join(ck)),
            "{ck}: weights differ from the uninterrupted run"
        );
    }
    assert_eq!(
        records(&full.join("metrics.jsonl")),
        records(&run.join("metrics.jsonl"))
    );

    // The kill that the timing above may or may not hit: after the new optimiser state was
    // written, before the checkpoint. Made exactly: a run stopped at 8, continued to 10, and
    // its checkpoint of 8 and that checkpoint's optimiser state (as the predecessor the
    // checkpointer keeps until the new checkpoint is written) put back.
    let cut = tmp.path().join("cut");
    let mut c = train(&data, &cut);
    c.args(["--stop-after", "8"]);
    ok(&output(&mut c));
    let at8 = std::fs::read(cut.join("last.safetensors")).unwrap();
    let optim8 = std::fs::read(cut.join("last.optim.safetensors")).unwrap();
    let mut c = train(&data, &cut);
    c.args(["--resume", "--stop-after", "10"]);
    ok(&output(&mut c));
    assert!(
        !cut.join("last.optim.prev.safetensors").exists(),
        "a finished checkpoint keeps no previous optimiser state"
    );
    std::fs::write(cut.join("last.optim.prev.safetensors"), &optim8).unwrap();
    std::fs::write(cut.join("last.safetensors"), &at8).unwrap();
    let mut c = train(&data, &cut);
    c.arg("--resume");
    ok(&output(&mut c));
    assert!(tensors(&full.join("last.safetensors")) == tensors(&cut.join("last.safetensors")));
    assert_eq!(
        records(&full.join("metrics.jsonl")),
        records(&cut.join("metrics.jsonl"))
    );

    // A full disk at the next checkpoint: the error names the file, the last checkpoint is
    // untouched and no temporary file stays; with room again, --resume ends as above.
    let disk = tmp.path().join("disk");
    let mut c = train(&data, &disk);
    c.args(["--stop-after", "8"]);
    ok(&output(&mut c));
    let before = std::fs::read(disk.join("last.safetensors")).unwrap();
    let mut c = train(&data, &disk);
    c.arg("--resume");
    let o = output(&mut limited(16, &c));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("File too large") && err.contains(".safetensors"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(disk.join("last.safetensors")).unwrap(),
        before
    );
    let stray: Vec<String> = std::fs::read_dir(&disk)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(stray.is_empty(), "{stray:?}");
    let mut c = train(&data, &disk);
    c.arg("--resume");
    ok(&output(&mut c));
    assert!(tensors(&full.join("best.safetensors")) == tensors(&disk.join("best.safetensors")));
}

fn records_or_empty(p: &Path) -> usize {
    std::fs::read_to_string(p).map_or(0, |t| {
        t.lines()
            .filter(|l| l.contains("\"kind\":\"epoch\"") || l.contains("\"kind\":\"iter\""))
            .count()
    })
}

/// Slurm's pre-emption (SIGTERM) in the middle of an epoch: the run checkpoints after its
/// current step, says where it stopped and how to continue, exits with 143, and the command it
/// names (`--resume`) ends with the weights and the metrics of an uninterrupted run.
#[test]
fn train_stopped_by_sigterm_resumes_to_the_uninterrupted_run() {
    let tmp = tempfile::tempdir().unwrap();
    let data = toy(tmp.path());
    let full = tmp.path().join("full");
    ok(&output(&mut train(&data, &full)));

    let run = tmp.path().join("term");
    let log = tmp.path().join("term.log");
    let mut c = train(&data, &run);
    c.stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap());
    let mut g = Guard::new(c.spawn().unwrap());
    let t = Instant::now();
    while records_or_empty(&run.join("metrics.jsonl")) < 3 {
        assert!(!g.ended(), "finished before the signal");
        assert!(t.elapsed() < Duration::from_secs(120), "too slow to start");
        std::thread::sleep(Duration::from_millis(2));
    }
    // SAFETY: kill(2) of our own running child.
    unsafe { libc::kill(g.child().id() as libc::pid_t, libc::SIGTERM) };
    let status = g.wait(Duration::from_secs(60));
    let err = std::fs::read_to_string(&log).unwrap();
    assert_eq!(status.code(), Some(143), "{err}");
    let line = err
        .lines()
        .find(|l| l.starts_with("interrupted at iteration "))
        .unwrap_or_else(|| panic!("no interruption line in:\n{err}"));
    assert!(line.contains(" of 32; continue with: "), "{line}");
    assert!(
        line.ends_with(" --resume") && line.contains("--max-val-samples 2"),
        "{line}"
    );
    assert!(!run.join("last.optim.prev.safetensors").exists());
    let mut c = train(&data, &run);
    c.arg("--resume");
    ok(&output(&mut c));
    for ck in ["last.safetensors", "best.safetensors"] {
        assert!(
            tensors(&full.join(ck)) == tensors(&run.join(ck)),
            "{ck}: weights differ from the uninterrupted run"
        );
    }
    assert_eq!(
        records(&full.join("metrics.jsonl")),
        records(&run.join("metrics.jsonl"))
    );
}
