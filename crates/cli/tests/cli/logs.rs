//! Long commands followed from a log file (stderr not a terminal: Slurm, nohup, CI): the real
//! binary with stderr sent to a file prints a start line, progress lines, a line per validation
//! and a closing line — where indicatif alone printed nothing but the closing summary.

use std::fs::File;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use crate::common::{tiny_train, Guard};

/// Runs `c` with stderr into `log` (a file, as `2> log` does) and returns the log's lines.
fn run_logged(mut c: Command, log: &Path) -> Vec<String> {
    let f = File::create(log).unwrap();
    c.stdout(Stdio::null())
        .stderr(Stdio::from(f))
        .env_remove("DEPTHSENSE_PROGRESS");
    let status = Guard::new(c.spawn().unwrap()).wait(Duration::from_secs(300));
    let text = std::fs::read_to_string(log).unwrap();
    assert!(status.success(), "{text}");
    text.lines().map(str::to_string).collect()
}

/// The lines that contain every one of `words`.
fn with<'a>(lines: &'a [String], words: &[&str]) -> Vec<&'a String> {
    lines
        .iter()
        .filter(|l| words.iter().all(|w| l.contains(w)))
        .collect()
}

/// `2026-12-03T15:40:01Z …`: a log line tells when it was written.
fn stamped(line: &str) -> bool {
    let b = line.as_bytes();
    b.len() > 21 && b[4] == b'-' && b[10] == b'T' && b[19] == b'Z' && b[20] == b' '
}

#[test]
fn train_into_a_log_file_prints_start_progress_validation_and_closing_lines() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    depthsense_data::write_toy_dataset(&data, 6, 4, 128, 64, 3).unwrap();
    let out = tmp.path().join("run");
    let mut c = tiny_train(&data, &out, 2);
    c.args(["--log-every", "1it", "--dropout", "0"]);
    let lines = run_logged(c, &tmp.path().join("train.log"));
    let all = lines.join("\n");

    let start = with(
        &lines,
        &["train: tiny (", "training /", "epochs ×", "batch 2"],
    );
    assert_eq!(start.len(), 1, "one start line:\n{all}");
    assert!(stamped(start[0]), "{all}");
    assert!(start[0].contains(&out.display().to_string()), "{all}");

    let progress = with(&lines, &["train: ", "loss", "lr", "img/s", "ETA"]);
    assert!(
        progress.len() >= 2,
        "progress lines every iteration:\n{all}"
    );
    assert!(progress.iter().all(|l| stamped(l)), "{all}");

    let before = with(&lines, &["train: validation before training: RMSE"]);
    let after = with(&lines, &["train: validation after epoch", "RMSE", "δ1"]);
    assert_eq!(before.len(), 1, "{all}");
    assert_eq!(after.len(), 2, "one line per epoch's validation:\n{all}");
    assert!(after[1].contains("epoch 2/2"), "{all}");

    assert_eq!(with(&lines, &["train: done,"]).len(), 1, "{all}");
    // The time of an epoch, measured on the first iterations (after the first), said once.
    let pace = with(
        &lines,
        &[
            "train: pace: ",
            "s per iteration over iterations 2–6",
            "an epoch of 8 iterations ≈",
        ],
    );
    assert_eq!(pace.len(), 1, "{all}");
    let closing = with(&lines, &["iterations of", "validation RMSE"]);
    assert_eq!(closing.len(), 1, "{all}");
    assert!(
        closing[0].contains("on 2 validation samples of"),
        "the closing line counts the validation samples used (--max-val-samples 2): {all}"
    );
    // Order: start, validations and progress, then the end.
    let pos = |l: &String| lines.iter().position(|x| x == l).unwrap();
    assert!(pos(start[0]) < pos(before[0]) && pos(after[1]) < pos(closing[0]));
}

#[test]
fn synth_and_prepare_into_a_log_file_print_start_progress_and_closing_lines() {
    let tmp = tempfile::tempdir().unwrap();
    let world = tmp.path().join("world");
    let mut c = Command::new(env!("CARGO_BIN_EXE_depthsense"));
    c.args(["synth", "--scenes", "1", "--keyframes-per-scene", "2"])
        .args(["--log-every", "1it", "--out"])
        .arg(&world);
    let lines = run_logged(c, &tmp.path().join("synth.log"));
    let all = lines.join("\n");
    assert_eq!(
        with(&lines, &["synth: 1 scenes × 2 keyframes", "→"]).len(),
        1,
        "{all}"
    );
    assert!(with(&lines, &["synth: ", "%)", "ETA"]).len() >= 2, "{all}");
    assert_eq!(with(&lines, &["synth: done,"]).len(), 1, "{all}");

    let mut c = Command::new(env!("CARGO_BIN_EXE_depthsense"));
    c.args(["prepare", "--version", "v1.0-synth", "--split", "all"])
        .args(["--lidar-sweeps", "1", "--log-every", "1it", "--dataroot"])
        .arg(&world)
        .arg("--out")
        .arg(tmp.path().join("prepared"));
    let lines = run_logged(c, &tmp.path().join("prepare.log"));
    let all = lines.join("\n");
    assert_eq!(
        with(
            &lines,
            &["prepare: 2 keyframes to prepare (0 already done)"]
        )
        .len(),
        1,
        "{all}"
    );
    assert_eq!(with(&lines, &["prepare: 2/2 (100 %)"]).len(), 1, "{all}");
    assert_eq!(with(&lines, &["prepare: done, 2/2"]).len(), 1, "{all}");
    assert!(
        lines.iter().all(|l| !l.contains('\r')),
        "no bar redraws in a log"
    );
}

#[test]
fn log_every_refuses_a_value_that_is_neither_a_duration_nor_a_step_count() {
    let o = Command::new(env!("CARGO_BIN_EXE_depthsense"))
        .args(["synth", "--log-every", "often", "--out", "nowhere"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("--log-every") && err.contains("100it"),
        "{err}"
    );
}
