//! The one rule for output folders (docs/guide/reliability.md): **a command never replaces results
//! that are already there unless told to.**
//!
//! - A *run folder* (`train`, `mer train`): one that holds a run is refused unless `--resume`
//!   (continue it) or `--force` (start over: the run's own files are removed first, and the
//!   command says what it replaced). Nothing else in the folder is touched.
//! - A *results folder* (`predict --out`, `eval --out`, `report --out`, `demo --out`): when any
//!   of the files the command is about to write exists, it refuses before computing anything,
//!   naming them; with `--force` it replaces exactly those files, each atomically (temporary
//!   sibling, then rename), and leaves every other file alone.
//! - While a command writes a run or a dataset in place, it holds the folder's lock
//!   ([`depthsense_base::lock`]); a second writer fails at once.

use std::path::{Path, PathBuf};

use crate::error::DataError;

// The files of a training run folder (SPEC §8; `trainer` re-exports them).
pub const CONFIG_FILE: &str = "config.json";
pub const METRICS_FILE: &str = "metrics.jsonl";
pub const CURVES_FILE: &str = "curves.png";
pub const LAST_CKPT: &str = "last.safetensors";
pub const LAST_OPTIM: &str = "last.optim.safetensors";
/// The optimiser state of the checkpoint before, kept while a new pair is written.
pub const PREV_OPTIM: &str = "last.optim.prev.safetensors";
pub const BEST_CKPT: &str = "best.safetensors";

/// The files of a training run (`train` and `mer train` write the same names), removed by
/// `--force`.
pub const RUN_FILES: [&str; 7] = [
    CONFIG_FILE,
    METRICS_FILE,
    CURVES_FILE,
    LAST_CKPT,
    LAST_OPTIM,
    PREV_OPTIM,
    BEST_CKPT,
];

/// What a run folder holds, read from its `metrics.jsonl`.
#[derive(Debug, Clone, PartialEq)]
pub struct RunHolds {
    /// Epochs with a validation record.
    pub epochs: u64,
    /// Best validation value and its epoch: lowest RMSE (`train`) or highest AUC (`mer train`).
    pub best: Option<(String, f64, u64)>,
}

impl std::fmt::Display for RunHolds {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (&self.best, self.epochs) {
            (_, 0) => write!(f, "a run with no finished epoch"),
            (Some((what, v, e)), n) => {
                write!(
                    f,
                    "a run of {n} epoch(s), best validation {what} {v:.3} at epoch {e}"
                )
            }
            (None, n) => write!(f, "a run of {n} epoch(s)"),
        }
    }
}

/// Whether `dir` holds a training run (any of [`RUN_FILES`]), and what.
pub fn run_in(dir: &Path) -> Option<RunHolds> {
    if !RUN_FILES.iter().any(|f| dir.join(f).exists()) {
        return None;
    }
    let text = std::fs::read_to_string(dir.join(METRICS_FILE)).unwrap_or_default();
    let mut epochs = 0u64;
    let mut best: Option<(String, f64, u64)> = None;
    for line in text.lines() {
        let Ok(v) = serde_json::from_str::<serde_json::Value>(line) else {
            continue;
        };
        if v.get("kind").and_then(|k| k.as_str()) != Some("epoch") {
            continue;
        }
        epochs += 1;
        let epoch = v["epoch"].as_u64().unwrap_or(epochs);
        let val = &v["val"];
        let candidate = if let Some(r) = val.get("rmse").and_then(|x| x.as_f64()) {
            Some(("RMSE (m)", r, true))
        } else {
            val.get("auc")
                .and_then(|x| x.as_f64())
                .map(|a| ("AUC", a, false))
        };
        if let Some((what, x, lower_is_better)) = candidate {
            let better = match &best {
                None => x.is_finite(),
                Some((_, b, _)) => {
                    if lower_is_better {
                        x < *b
                    } else {
                        x > *b
                    }
                }
            };
            if better {
                best = Some((what.to_string(), x, epoch));
            }
        }
    }
    Some(RunHolds { epochs, best })
}

/// The run-folder rule for `command` (e.g. `train`) writing into `dir`: refuse a folder that
/// holds a run unless `resume` or `force`; with `force` (and no `resume`) remove the run's
/// files and say so on stderr. Returns what was replaced.
pub fn claim_run_folder(
    dir: &Path,
    command: &str,
    resume: bool,
    force: bool,
) -> Result<Option<RunHolds>, DataError> {
    let Some(holds) = run_in(dir) else {
        return Ok(None);
    };
    if resume {
        return Ok(None);
    }
    if !force {
        return Err(DataError::OutputExists {
            dir: dir.to_path_buf(),
            what: holds.to_string(),
            advice: format!(
                "continue it with `{command} --resume`, start over with `{command} --force` \
                 (removes its {}), or choose another --out",
                RUN_FILES.join(", ")
            ),
        });
    }
    eprintln!(
        "--force: replacing {holds} in {} (its {} are removed)",
        dir.display(),
        RUN_FILES.join(", ")
    );
    for f in RUN_FILES {
        let p = dir.join(f);
        match std::fs::remove_file(&p) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(DataError::io(&p, e)),
        }
    }
    Ok(Some(holds))
}

/// The results-folder rule: `files` are what `command` is about to write; when some exist and
/// `force` is not given, refuse (naming up to five of them and the count). With `force`, say
/// how many will be replaced.
pub fn refuse_existing(files: &[PathBuf], force: bool, command: &str) -> Result<(), DataError> {
    let existing: Vec<&PathBuf> = files.iter().filter(|p| p.exists()).collect();
    if existing.is_empty() {
        return Ok(());
    }
    let dir = existing[0]
        .parent()
        .map_or_else(|| PathBuf::from("."), Path::to_path_buf);
    if force {
        eprintln!(
            "--force: replacing {} file(s) of an earlier `{command}` in {}",
            existing.len(),
            dir.display()
        );
        return Ok(());
    }
    let names: Vec<String> = existing
        .iter()
        .take(5)
        .map(|p| {
            p.file_name().map_or_else(
                || p.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            )
        })
        .collect();
    let more = if existing.len() > 5 {
        format!(" and {} more", existing.len() - 5)
    } else {
        String::new()
    };
    Err(DataError::OutputExists {
        dir,
        what: format!(
            "results of an earlier `{command}` ({}{more})",
            names.join(", ")
        ),
        advice: format!(
            "pass --force to replace them (only the files `{command}` writes, each atomically) \
             or choose another --out"
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn epoch_line(e: u64, rmse: f64) -> String {
        format!(
            "{{\"kind\":\"epoch\",\"epoch\":{e},\"iteration\":{},\"val\":{{\"rmse\":{rmse}}}}}\n",
            e * 10
        )
    }

    #[test]
    fn a_run_folder_is_described_refused_and_forced() {
        let d = tempfile::tempdir().unwrap();
        assert!(claim_run_folder(d.path(), "train", false, false)
            .unwrap()
            .is_none());
        let metrics = format!(
            "{{\"kind\":\"iter\",\"iteration\":1,\"loss\":3.0}}\n{}{}{}",
            epoch_line(1, 12.0),
            epoch_line(2, 9.5),
            epoch_line(3, 10.1)
        );
        std::fs::write(d.path().join(METRICS_FILE), metrics).unwrap();
        std::fs::write(d.path().join(BEST_CKPT), b"x").unwrap();
        std::fs::write(d.path().join("notes.txt"), b"mine").unwrap();
        let holds = run_in(d.path()).unwrap();
        assert_eq!(holds.epochs, 3);
        assert_eq!(holds.best, Some(("RMSE (m)".into(), 9.5, 2)));
        let e = claim_run_folder(d.path(), "train", false, false)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(&d.path().display().to_string())
                && e.contains("3 epoch(s), best validation RMSE (m) 9.500 at epoch 2")
                && e.contains("--resume")
                && e.contains("--force"),
            "{e}"
        );
        assert!(d.path().join(BEST_CKPT).exists(), "refusal changes nothing");
        assert!(claim_run_folder(d.path(), "train", true, false)
            .unwrap()
            .is_none());
        let replaced = claim_run_folder(d.path(), "train", false, true).unwrap();
        assert_eq!(replaced.unwrap().epochs, 3);
        assert!(!d.path().join(BEST_CKPT).exists() && !d.path().join(METRICS_FILE).exists());
        assert!(d.path().join("notes.txt").exists(), "not the run's: kept");
    }

    #[test]
    fn mer_runs_report_their_best_auc() {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(
            d.path().join(METRICS_FILE),
            "{\"kind\":\"epoch\",\"epoch\":1,\"val\":{\"auc\":0.7}}\n\
             {\"kind\":\"epoch\",\"epoch\":2,\"val\":{\"auc\":0.8}}\n",
        )
        .unwrap();
        let h = run_in(d.path()).unwrap();
        assert_eq!(h.best, Some(("AUC".into(), 0.8, 2)));
        // config.json alone: a run that never finished an epoch
        let d2 = tempfile::tempdir().unwrap();
        std::fs::write(d2.path().join(CONFIG_FILE), "{}").unwrap();
        assert_eq!(
            run_in(d2.path()).unwrap().to_string(),
            "a run with no finished epoch"
        );
    }

    #[test]
    fn existing_results_are_refused_unless_forced() {
        let d = tempfile::tempdir().unwrap();
        let files: Vec<PathBuf> = (0..7).map(|i| d.path().join(format!("t{i}.png"))).collect();
        refuse_existing(&files, false, "predict").unwrap();
        for f in &files {
            std::fs::write(f, b"old").unwrap();
        }
        let e = refuse_existing(&files, false, "predict")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("t0.png") && e.contains("and 2 more") && e.contains("--force"),
            "{e}"
        );
        refuse_existing(&files, true, "predict").unwrap();
    }
}
