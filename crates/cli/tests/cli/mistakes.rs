//! Errors name the cause once and the next step: a table of a user's mistakes driven through the
//! real binary, each checked for its cause, its next step and for saying nothing twice; and
//! what `eval` / `predict` / `train` do with unreadable prepared samples: `eval` names every
//! one at once with how to rebuild them, `predict --data` does not read the ground truth it does
//! not need, `prepare --verify` rebuilds them, and a `train` that fails before its first
//! checkpoint leaves no run folder behind.

use std::path::{Path, PathBuf};

use crate::common::{ok, run, synth_and_prepare, tiny_train, PREPARE};

/// Something a line of the error says twice: a `: `-separated part of ten characters or more
/// that occurs again in its line (`x: not found: not found`).
fn repeated(err: &str) -> Option<String> {
    err.lines().find_map(|line| {
        line.split(": ")
            .map(str::trim)
            .filter(|p| p.len() >= 10)
            .find(|p| line.matches(*p).count() > 1)
            .map(str::to_string)
    })
}

/// A small world, its prepared folder, a toy prepared folder and a checkpoint trained on it.
struct Setup {
    tmp: tempfile::TempDir,
}

impl Setup {
    fn new() -> Setup {
        let tmp = tempfile::tempdir().unwrap();
        let t = tmp.path();
        synth_and_prepare(t, 5, 1);
        depthsense_data::write_toy_dataset(&t.join("toy"), 6, 4, 128, 64, 3).unwrap();
        let mut c = tiny_train(&t.join("toy"), &t.join("run"), 1);
        c.args(["--max-batches-per-epoch", "1"]);
        ok(&c.output().unwrap());
        // A sharded preparation whose shard indexes were never merged.
        std::fs::create_dir_all(t.join("sharded")).unwrap();
        std::fs::copy(
            t.join("prepared/index.json"),
            t.join("sharded/index.shard-0-of-2.json"),
        )
        .unwrap();
        Setup { tmp }
    }

    fn path(&self, p: &str) -> PathBuf {
        self.tmp.path().join(p)
    }
}

/// (what the user typed, what the cause must say, what the next step must say).
const MISTAKES: &[(&str, &[&str], &[&str])] = &[
    (
        "prepare --dataroot world --out p2",
        &["world: no version folder `v1.0-mini`"],
        &["--version v1.0-synth"],
    ),
    (
        "prepare --dataroot wrold --version v1.0-synth --out p2",
        &["wrold: no such dataroot folder"],
        &["samples/"],
    ),
    (
        "train --data prepard --config tiny --out r",
        &["prepard: no such folder"],
        &["prepared folders beside it: prepared, toy"],
    ),
    (
        "train --data world --config tiny --out r",
        &["world is a nuScenes dataroot (v1.0-synth)"],
        &["depthsense prepare --dataroot world --version v1.0-synth --out FOLDER"],
    ),
    (
        "train --data sharded --config tiny --out r",
        &["index.shard-0-of-2.json", "no index.json"],
        &["depthsense index merge sharded"],
    ),
    (
        "train --data toy --config tiny-wider --out r",
        &["unknown model preset `tiny-wider`"],
        &["paper, released, tiny, tiny-wide"],
    ),
    (
        "train --data toy --config tiny --set radar-skipp=8 --out r",
        &["unknown option `radar-skipp`"],
        &["did you mean `radar-skip`?"],
    ),
    (
        "eval --checkpoint run/bset.safetensors --data toy --out e",
        &["run/bset.safetensors: no such file"],
        &["checkpoints in run: run/best.safetensors"],
    ),
    (
        "predict --checkpoint run/best.safetensors --sample toy --out pr",
        &["toy is a prepared folder, not one sample"],
        &["--sample toy/<sample token>", "--data toy"],
    ),
    (
        "eval --predictions preds --data toy --out e",
        &["preds: no such folder"],
        &["depthsense predict --data"],
    ),
    (
        "index merge toy",
        &["nothing to merge"],
        &["prepare --shard I/N --out OUT"],
    ),
    (
        "train --data toy --config tiny --extend --epochs 3 --out nothing",
        &["nothing holds no run to extend"],
        &["without --extend"],
    ),
    (
        "mer apply --checkpoint pda/best.safetensors --data toy",
        &["pda/best.safetensors: no such file"],
        &["depthsense mer train"],
    ),
    (
        "synth --out w2 --log-every often",
        &["--log-every \"often\""],
        &["100it"],
    ),
    // Refused before any work (docs/guide/reliability.md, "Refused before any work").
    (
        "eval --checkpoint run/best.safetensors --data toy --out /proc/x",
        &["--out /proc/x: cannot create files in /proc"],
        &["choose a folder you can write to"],
    ),
    (
        "synth --out /proc/x --scenes 1",
        &["--out /proc/x: cannot create files in /proc"],
        &["choose a folder you can write to"],
    ),
    (
        "report --runs run --out /proc/x",
        &["--out /proc/x: cannot create files in /proc"],
        &["choose a folder you can write to"],
    ),
    (
        "train --data toy --config tiny --lr=-1 --out r",
        &["invalid value '-1' for '--lr <LR>'"],
        &["must be greater than 0"],
    ),
    (
        "train --data toy --config tiny --epochs -3 --out r",
        &["invalid value '-3' for '--epochs <EPOCHS>'"],
        &["must be at least 1"],
    ),
    (
        "train --data toy --config tiny --dropout 1.5 --out r",
        &["invalid value '1.5' for '--dropout <DROPOUT>'"],
        &["must be between 0 and 1"],
    ),
    (
        "predict --checkpoint run/best.safetensors --image frame.jpg --out pr",
        &["--image needs --calibration FILE.json"],
        &["depthsense calibration --dataroot DATAROOT --version VERSION --token SAMPLE_TOKEN"],
    ),
];

#[test]
fn every_mistake_names_its_cause_once_and_the_next_step() {
    let s = Setup::new();
    let mut problems = vec![];
    for (typed, causes, next) in MISTAKES {
        let args: Vec<&str> = typed.split(' ').collect();
        let o = run(&args, s.tmp.path());
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        let says = |w: &&str| err.contains(*w);
        if o.status.success() {
            problems.push(format!("`{typed}` succeeded"));
        } else if !causes.iter().all(says) || !next.iter().all(says) {
            problems.push(format!("`{typed}`:\n{err}"));
        } else if let Some(twice) = repeated(&err) {
            problems.push(format!("`{typed}` says `{twice}` twice:\n{err}"));
        }
    }
    assert!(MISTAKES.len() >= 12);
    assert!(problems.is_empty(), "{}", problems.join("\n---\n"));
    // None of the failed trains left a run folder behind.
    for out in ["r", "nothing", "pr", "e"] {
        assert!(!s.path(out).exists(), "a failed command left {out}/");
    }
    // A missing checkpoint lists the loadable ones beside it, not the optimiser states.
    let o = run(
        &[
            "eval",
            "--checkpoint",
            "run/bset.safetensors",
            "--data",
            "toy",
        ],
        s.tmp.path(),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("run/last.safetensors") && !err.contains("optim"),
        "{err}"
    );
    // A run folder as --checkpoint is its best.safetensors, said once.
    let o = run(
        &[
            "eval",
            "--checkpoint",
            "run",
            "--data",
            "toy",
            "--out",
            "e-run",
        ],
        s.tmp.path(),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert_eq!(
        err.matches("run: a run folder; using its best.safetensors")
            .count(),
        1,
        "{err}"
    );
}

/// Truncates a file to half its length (a copy cut short).
fn truncate(p: &Path) {
    let bytes = std::fs::read(p).unwrap();
    std::fs::write(p, &bytes[..bytes.len() / 2]).unwrap();
}

#[test]
fn unreadable_samples_are_named_together_and_rebuilt_by_prepare_verify() {
    let s = Setup::new();
    let t = s.tmp.path();
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(s.path("toy/index.json")).unwrap()).unwrap();
    let dirs: Vec<String> = index["samples"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["dir"].as_str().unwrap().to_string())
        .collect();
    // Two samples lose their lidar ground truth: eval names both; predict --data, which needs
    // no ground truth, runs.
    for d in &dirs[..2] {
        truncate(&s.path(&format!("toy/{d}/lidar_sparse.png")));
    }
    let o = run(
        &[
            "eval",
            "--checkpoint",
            "run/best.safetensors",
            "--data",
            "toy",
            "--split",
            "all",
        ],
        t,
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("2 prepared sample(s) of toy cannot be read"),
        "{err}"
    );
    for d in &dirs[..2] {
        assert!(err.contains(&format!("{d}/lidar_sparse.png")), "{err}");
    }
    assert!(err.contains("--verify"), "{err}");
    assert!(repeated(&err).is_none(), "{err}");
    let o = run(
        &[
            "predict",
            "--checkpoint",
            "run/best.safetensors",
            "--data",
            "toy",
            "--split",
            "all",
            "--out",
            "preds",
        ],
        t,
    );
    ok(&o);

    // A real prepared folder: a truncated image stops train with the same advice, and
    // `prepare --verify` rebuilds exactly the broken sample.
    let index: serde_json::Value =
        serde_json::from_slice(&std::fs::read(s.path("prepared/index.json")).unwrap()).unwrap();
    let train_sample = index["samples"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["splits"].as_array().unwrap().iter().any(|s| s == "train"))
        .expect("a training sample");
    let first = train_sample["dir"].as_str().unwrap().to_string();
    let image = s.path(&format!("prepared/{first}/image.png"));
    let good = std::fs::read(&image).unwrap();
    truncate(&image);
    let mut c = tiny_train(&s.path("prepared"), &s.path("r2"), 1);
    c.args(["--set", "input-downscale=4"]);
    let o = c.output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains(&format!("{first}/image.png")) && err.contains("--verify"),
        "{err}"
    );
    let o = run(&[&PREPARE[..], &["--verify"]].concat(), t);
    ok(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("verified 5 samples already there: 1 broken, prepared again"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(&image).unwrap(),
        good,
        "rebuilt byte for byte"
    );
}
