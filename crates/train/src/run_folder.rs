//! A training run's folder as the engine holds it ([`crate::learner::fit`] and the learners that
//! it drives — `train`'s and `mer train`'s): taken for one writer ([`OutputLock`]), a folder that
//! holds a run refused unless the run continues or is replaced ([`claim_run_folder`]), and its
//! records written only through it: RUN/metrics.jsonl ([`RunFolder::log`],
//! [`RunFolder::append`]) and RUN/config.json ([`RunFolder::write_config`]). Only the process
//! that writes RUN/ holds one
//! (rank 0 of a data-parallel job, or the only process).

use std::path::{Path, PathBuf};

use depthsense_base::lock::OutputLock;
use depthsense_dataset::outputs::{claim_run_folder, CONFIG_FILE, METRICS_FILE};
use depthsense_infer::NetError;
use depthsense_records::metrics_log::MetricsRecord;
use serde::Serialize;

use crate::metrics_log::{append_jsonl, truncate_metrics};

/// A run folder taken by this process; the lock is held while it lives.
pub struct RunFolder {
    dir: PathBuf,
    _lock: OutputLock,
}

impl RunFolder {
    /// Takes `out` for `depthsense {command}` alone and refuses a folder that holds a run unless
    /// `resume` (it continues) or `force` (its run files are removed first); the lock creates
    /// the folder.
    pub fn take(out: &Path, command: &str, resume: bool, force: bool) -> Result<Self, NetError> {
        let lock = OutputLock::exclusive(out, &format!("depthsense {command}"))?;
        claim_run_folder(out, command, resume, force)?;
        Ok(Self {
            dir: out.to_path_buf(),
            _lock: lock,
        })
    }

    /// RUN/`name`.
    pub fn file(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Writes RUN/config.json (the run's typed record: `train`'s `TrainRunConfig`, `mer
    /// train`'s `MerRunConfig`), whole or not at all (a temporary file, then a rename).
    pub fn write_config<C: Serialize>(&self, config: &C) -> Result<(), NetError> {
        let path = self.file(CONFIG_FILE);
        let text = depthsense_records::to_json_pretty(config)?;
        depthsense_base::fsutil::write_atomic(&path, text.as_bytes())
            .map_err(|e| NetError::io(&path, e))
    }

    /// Appends one record to RUN/metrics.jsonl.
    pub fn log(&self, record: &serde_json::Value) -> Result<(), NetError> {
        append_jsonl(&self.file(METRICS_FILE), record)
    }

    /// Appends one typed record (an iteration's, an epoch's) to RUN/metrics.jsonl.
    pub fn append<V: Serialize>(&self, record: &MetricsRecord<V>) -> Result<(), NetError> {
        self.log(&record.to_value()?)
    }

    /// RUN/metrics.jsonl for a run that starts at global iteration `iteration`: gone for a
    /// fresh run (0), cut after `iteration` for a resumed one (the lines after its checkpoint
    /// are trained again).
    pub fn restart_log(&self, iteration: u64) -> Result<(), NetError> {
        let metrics = self.file(METRICS_FILE);
        if iteration > 0 {
            return truncate_metrics(&metrics, iteration);
        }
        match std::fs::remove_file(&metrics) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(NetError::io(&metrics, e)),
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_folder_is_taken_once_and_its_log_restarts_with_the_run() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("run");
        let f = RunFolder::take(&out, "train", false, false).unwrap();
        assert!(out.is_dir());
        // A second writer is refused while the first holds it.
        assert!(RunFolder::take(&out, "train", true, false).is_err());
        for it in 1..=3u64 {
            let line =
                serde_json::json!({"kind": "iter", "epoch": 0, "iteration": it, "loss": 1.0});
            f.log(&line).unwrap();
        }
        f.restart_log(2).unwrap();
        let text = std::fs::read_to_string(f.file(METRICS_FILE)).unwrap();
        assert_eq!(text.lines().count(), 2, "{text}");
        f.restart_log(0).unwrap();
        assert!(!f.file(METRICS_FILE).exists());
        f.restart_log(0).unwrap();
        f.write_config(&serde_json::json!({"format_version": 1}))
            .unwrap();
        let text = std::fs::read_to_string(f.file(CONFIG_FILE)).unwrap();
        assert!(text.contains("\"format_version\": 1"), "{text}");
    }
}
