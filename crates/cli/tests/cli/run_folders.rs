//! Nothing lost, nothing written twice (docs/guide/reliability.md), with the real binary:
//! a second `train` into a finished run folder is refused and changes no byte; two `train`s on
//! one folder — the second fails at once naming the first, the first completes; a process
//! killed while holding the lock leaves no lock behind. Every child is killed on failure and
//! every wait has a deadline.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use depthsense_base::lock::{OutputLock, LOCK_FILE};

use crate::common;
use common::{tiny_train, Guard};

fn train_cmd(data: &Path, out: &Path, epochs: u32) -> Command {
    let mut c = tiny_train(data, out, epochs);
    c.args(["--dropout", "0"]);
    c
}

fn run(mut c: Command) -> Output {
    c.output().unwrap()
}

/// Every file of `dir` (but the lock file) with its bytes.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut m = BTreeMap::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_file() && p.file_name().unwrap() != LOCK_FILE {
            m.insert(p.clone(), std::fs::read(&p).unwrap());
        }
    }
    m
}

fn wait_until_locked(dir: &Path, child: &mut Guard) {
    let t = Instant::now();
    while !OutputLock::is_held(dir) {
        assert!(
            !child.ended(),
            "the first train ended before it was seen holding the lock"
        );
        assert!(t.elapsed() < Duration::from_secs(60), "no lock after 60 s");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn toy(tmp: &Path) -> PathBuf {
    let data = tmp.join("data");
    depthsense_data::write_toy_dataset(&data, 6, 4, 128, 64, 3).unwrap();
    data
}

#[test]
fn a_finished_run_is_refused_unchanged_and_replaced_only_with_force() {
    let tmp = tempfile::tempdir().unwrap();
    let data = toy(tmp.path());
    let out = tmp.path().join("run");
    let o = run(train_cmd(&data, &out, 1));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let before = snapshot(&out);
    assert!(before.contains_key(&out.join("best.safetensors")));

    let o = run(train_cmd(&data, &out, 1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success(),
        "a second train into a finished run succeeded"
    );
    assert!(
        err.contains(&out.display().to_string())
            && err.contains("already holds a run of 1 epoch(s), best validation RMSE")
            && err.contains("--resume")
            && err.contains("--force"),
        "{err}"
    );
    assert_eq!(snapshot(&out), before, "a refused train changed the run");

    // --nproc is refused by the launcher, before any worker starts.
    let mut c = train_cmd(&data, &out, 1);
    c.args(["--nproc", "2"]);
    let o = run(c);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("already holds a run"));
    assert_eq!(snapshot(&out), before);

    let mut c = train_cmd(&data, &out, 1);
    c.arg("--force");
    let o = run(c);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("--force: replacing a run of 1 epoch(s)"),
        "{err}"
    );
}

#[test]
fn a_second_writer_fails_at_once_and_the_first_completes() {
    let tmp = tempfile::tempdir().unwrap();
    let data = toy(tmp.path());
    let out = tmp.path().join("run");
    let mut first = train_cmd(&data, &out, 6);
    first.stdout(Stdio::null()).stderr(Stdio::piped());
    let mut first = Guard::new(first.spawn().unwrap());
    let pid = first.child().id();
    wait_until_locked(&out, &mut first);

    let t = Instant::now();
    let o = run(train_cmd(&data, &out, 6));
    let took = t.elapsed();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "two trains on one folder");
    assert!(
        err.contains(&format!(
            "another depthsense process (pid {pid}, `depthsense train`"
        )) && err.contains(&out.display().to_string()),
        "{err}"
    );
    eprintln!("the second train failed after {took:?}");
    assert!(
        !first.ended(),
        "the second must fail while the first still runs (it took {took:?})"
    );
    // --force does not get past the lock either.
    let mut c = train_cmd(&data, &out, 6);
    c.arg("--force");
    assert!(!run(c).status.success());

    let status = first.wait(Duration::from_secs(300));
    assert!(status.success(), "the first train failed");
    assert!(out.join("best.safetensors").exists());
    let metrics = std::fs::read_to_string(out.join("metrics.jsonl")).unwrap();
    assert_eq!(
        metrics.matches("\"kind\":\"epoch\"").count(),
        6,
        "{metrics}"
    );
}

#[test]
fn a_killed_holder_leaves_no_lock_behind() {
    let tmp = tempfile::tempdir().unwrap();
    let data = toy(tmp.path());
    let out = tmp.path().join("run");
    let mut first = train_cmd(&data, &out, 50);
    first.stdout(Stdio::null()).stderr(Stdio::null());
    let mut first = Guard::new(first.spawn().unwrap());
    wait_until_locked(&out, &mut first);
    first.kill(); // SIGKILL
    assert!(out.join(LOCK_FILE).exists(), "the lock file stays");
    assert!(!OutputLock::is_held(&out), "the kernel released the lock");
    // The folder holds the killed run's start: refused without --force, taken with it.
    let mut c = train_cmd(&data, &out, 1);
    c.arg("--force");
    let o = run(c);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
