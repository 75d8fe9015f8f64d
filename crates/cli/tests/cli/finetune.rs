//! Fine-tuning and longer runs, with the real binary: `--resume` of a finished run says so and
//! changes nothing; `--extend --epochs N` continues it with a new learning-rate schedule that
//! config.json records; `--init-from` starts a fresh run from a checkpoint's weights (its first
//! validation equals the checkpoint's) and reports the tensors that are new.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Output;

use crate::common::tiny_train;

fn ok(o: &Output) -> String {
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{err}");
    err
}

fn json(p: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

/// RUN/metrics.jsonl's records.
fn records(run: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// Every file of `dir` but the lock, with its bytes.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file() && !p.ends_with(".depthsense.lock"))
        .map(|p| (p.clone(), std::fs::read(&p).unwrap()))
        .collect()
}

#[test]
fn a_finished_run_is_said_finished_extended_with_a_new_schedule_and_fine_tuned_from() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    depthsense_data::write_toy_dataset(&data, 6, 4, 128, 64, 3).unwrap();
    let run = tmp.path().join("run");
    let train = |epochs: u32, extra: &[&str]| {
        let mut c = tiny_train(&data, &run, epochs);
        c.args(["--max-batches-per-epoch", "2", "--lr", "0.002"])
            .args(extra);
        c.output().unwrap()
    };
    ok(&train(1, &[]));

    // --resume of the finished run: exit 0, said finished, nothing touched.
    let before = snapshot(&run);
    let err = ok(&train(1, &["--resume"]));
    assert!(
        err.contains("is finished: 1 of 1 epochs (iteration 2)") && err.contains("--extend"),
        "{err}"
    );
    assert!(!err.contains("img/s"), "{err}");
    assert_eq!(snapshot(&run), before);
    // The finished check reads the checkpoint's header only; a finished run resumed with
    // another schedule or another model is still refused, saying what differs (the same preset
    // with another --set: the field, by its key).
    for (extra, says) in [
        (
            &["--lr", "0.003"][..],
            &["was trained with batch 2 epochs 1 lr 0.002 seed 0; an exact resume needs the same \
               values (got batch 2 epochs 1 lr 0.003 seed 0)"][..],
        ),
        (
            &["--lr", "0.002", "--set", "dropout=0.3"][..],
            &[
                "holds a different model config than requested (checkpoint preset \"tiny\", \
                 requested \"tiny\"; dropout: ",
                " in the checkpoint, 0.3 requested); resume with the same --config and --set",
            ],
        ),
    ] {
        let mut c = tiny_train(&data, &run, 1);
        c.args(["--max-batches-per-epoch", "2", "--resume"])
            .args(extra);
        let o = c.output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && says.iter().all(|s| err.contains(s)),
            "{extra:?}: {err}"
        );
    }
    assert_eq!(snapshot(&run), before);

    // --extend to the same number of epochs: refused with the next step.
    let o = train(1, &["--extend"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("give more with --epochs"),
        "{err}"
    );

    // --extend --epochs 3 at another lr: two more epochs, a new poly schedule from 0.001.
    let extended = ok(&{
        let mut c = tiny_train(&data, &run, 3);
        c.args(["--max-batches-per-epoch", "2", "--lr", "0.001", "--extend"]);
        c.output().unwrap()
    });
    let cfg = json(&run.join("config.json"));
    let schedule = cfg["schedule"]
        .as_array()
        .expect("config.json records the schedule");
    assert_eq!(schedule.len(), 2, "{cfg}");
    assert_eq!(schedule[0]["lr"], 0.002);
    assert_eq!(schedule[1]["start_iteration"], 2);
    assert_eq!(schedule[1]["end_iteration"], 6);
    assert_eq!(schedule[1]["lr"], 0.001);
    let iters: Vec<(u64, f64)> = records(&run)
        .iter()
        .filter(|r| r["kind"] == "iter")
        .map(|r| (r["iteration"].as_u64().unwrap(), r["lr"].as_f64().unwrap()))
        .collect();
    assert_eq!(
        iters.iter().map(|i| i.0).collect::<Vec<_>>(),
        [1, 2, 3, 4, 5, 6]
    );
    assert_eq!(iters[0].1, 0.002, "the first step of the run: its own lr");
    assert_eq!(
        iters[2].1, 0.001,
        "the first step of the extension: the new lr"
    );
    assert!(iters[5].1 < iters[2].1, "decaying towards the new end");
    // The closing line says what best.safetensors holds and whether the extension changed it:
    // the lowest validation of the whole run, the one before training included.
    let (best_it, best_epoch) = best_of(&records(&run));
    let said = if best_it <= 2 {
        "unchanged by this run"
    } else {
        "written by this run"
    };
    assert!(
        extended.contains(&format!(
            "best.safetensors: epoch {best_epoch} (iteration {best_it})"
        )) || (best_it == 0 && extended.contains("the network before training")),
        "{extended}"
    );
    assert!(extended.contains(said), "{extended}");
    let err = ok(&{
        let mut c = tiny_train(&data, &run, 3);
        c.args(["--max-batches-per-epoch", "2", "--lr", "0.001", "--resume"]);
        c.output().unwrap()
    });
    assert!(err.contains("is finished: 3 of 3 epochs"), "{err}");

    // --init-from the run's best checkpoint into a fresh run (another seed) of the same
    // network: every tensor loaded, so its first validation is the checkpoint's.
    let best_rmse = records(&run)
        .iter()
        .filter(|r| r["kind"] == "epoch")
        .map(|r| r["val"]["rmse"].as_f64().unwrap())
        .fold(f64::INFINITY, f64::min);
    let tuned = tmp.path().join("tuned");
    let mut c = tiny_train(&data, &tuned, 1);
    c.args(["--max-batches-per-epoch", "1", "--seed", "9", "--init-from"])
        .arg(run.join("best.safetensors"));
    let err = ok(&c.output().unwrap());
    assert!(
        err.contains("initialised from") && err.contains("0 left random"),
        "{err}"
    );
    let first = &records(&tuned)[0];
    assert_eq!(first["kind"], "val");
    assert_eq!(first["val"]["rmse"].as_f64().unwrap(), best_rmse);
    // The validation before training is a candidate for best: when the fine-tuning epoch does
    // not beat it, best.safetensors keeps the weights it started from.
    let (best_it, _) = best_of(&records(&tuned));
    if best_it == 0 {
        assert!(
            err.contains("best.safetensors: the network before training (iteration 0)"),
            "{err}"
        );
        assert!(
            crate::common::tensors(&tuned.join("best.safetensors"))
                == crate::common::tensors(&run.join("best.safetensors")),
            "best.safetensors holds the weights the fine-tuning started from"
        );
    } else {
        assert!(
            err.contains("best.safetensors: epoch 1 (iteration 1)"),
            "{err}"
        );
    }
    assert!(err.contains("written by this run"), "{err}");
    let init = &json(&tuned.join("config.json"))["init_from"];
    assert!(init["loaded"].as_u64().unwrap() > 50, "{init}");
    assert_eq!(init["new"].as_array().unwrap().len(), 0, "{init}");

    // With a part the checkpoint lacks (attention on a run trained without it): named new.
    let plain = tmp.path().join("plain");
    let mut c = tiny_train(&data, &plain, 1);
    c.args(["--max-batches-per-epoch", "1", "--no-attention"]);
    ok(&c.output().unwrap());
    let with = tmp.path().join("with");
    let mut c = tiny_train(&data, &with, 1);
    c.args(["--max-batches-per-epoch", "1", "--init-from"])
        .arg(plain.join("best.safetensors"));
    let err = ok(&c.output().unwrap());
    assert!(err.contains("left random: attention.conv"), "{err}");
    let new = json(&with.join("config.json"))["init_from"]["new"].clone();
    assert!(
        new.as_array()
            .unwrap()
            .iter()
            .all(|k| k.as_str().unwrap().starts_with("attention.")),
        "{new}"
    );
}

/// (iteration, epoch) of the lowest validation RMSE in a run's records, the validation before
/// training (epoch 0) included; the earliest on a tie.
fn best_of(records: &[serde_json::Value]) -> (u64, u64) {
    let mut best = (f64::INFINITY, 0, 0);
    for r in records
        .iter()
        .filter(|r| r["kind"] == "val" || r["kind"] == "epoch")
    {
        let rmse = r["val"]["rmse"].as_f64().unwrap();
        if rmse < best.0 {
            best = (
                rmse,
                r["iteration"].as_u64().unwrap(),
                r["epoch"].as_u64().unwrap(),
            );
        }
    }
    (best.1, best.2)
}
