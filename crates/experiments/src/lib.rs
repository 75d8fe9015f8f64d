//! depthsense-experiments (layer 8, ARCHITECTURE.md): the experiments of SPEC §10 built from
//! ordinary training runs and evaluations, and the end-to-end [`demo`]:
//!
//! - [`ablation`]: the fusion variants of SPEC §6 (RGB only, early, late, late + spatial
//!   attention) and the loss ablation of SPEC §10.4 (ordinal vs L1 vs L2), several seeds each,
//!   reported on the test scenes as mean ± std over seeds.
//!
//! Shared here: seed statistics ([`Stat`]) and the description of the machine ([`Machine`]).

pub mod ablation;
pub mod cost;
pub mod data_scale;
pub mod demo;
pub mod error;
pub mod failure;
pub mod paired;
pub mod perturb;
pub mod reduced_data;
pub mod runner;

pub use error::{ExperimentError, SpecRefusal};

use serde::{Deserialize, Serialize};

/// Mean and sample standard deviation of one quantity over seeds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Stat {
    pub mean: f64,
    /// Sample standard deviation (divisor n − 1); `None` when n < 2.
    pub std: Option<f64>,
    /// Number of values (seeds) behind the mean.
    pub n: usize,
}

impl Stat {
    /// Mean and sample std (n − 1) of the finite values of `xs`; `None` when there are none.
    pub fn of(xs: &[f64]) -> Option<Stat> {
        let v: Vec<f64> = xs.iter().copied().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        let n = v.len();
        let mean = v.iter().sum::<f64>() / n as f64;
        let std = (n >= 2).then(|| {
            let ss: f64 = v.iter().map(|x| (x - mean) * (x - mean)).sum();
            (ss / (n - 1) as f64).sqrt()
        });
        Some(Stat { mean, std, n })
    }

    /// A Markdown cell: "4.123 ± 0.051" with 3 decimals, or "–" when there is no value.
    pub fn md_cell(s: Option<Stat>) -> String {
        depthsense_metrics::table::md_or_missing(s.map(|s| s.fmt(3)))
    }

    /// "4.123 ± 0.051" (std "–" when n < 2), values with `prec` decimals.
    pub fn fmt(&self, prec: usize) -> String {
        match self.std {
            Some(s) => format!("{:.prec$} ± {:.prec$}", self.mean, s),
            None => format!("{:.prec$} ± –", self.mean),
        }
    }
}

/// The machine an experiment ran on (recorded with its results).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Machine {
    /// Logical CPUs available to this process (`nproc`).
    pub nproc: usize,
    /// `model name` of /proc/cpuinfo when readable.
    pub cpu_model: Option<String>,
    pub os: String,
    pub arch: String,
    /// The torch device the runs used, in words.
    pub device: String,
}

impl Machine {
    pub fn describe(device: tch::Device) -> Machine {
        let cpu_model = std::fs::read_to_string("/proc/cpuinfo").ok().and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.trim().to_string())
        });
        Machine {
            nproc: std::thread::available_parallelism().map_or(1, |n| n.get()),
            cpu_model,
            os: std::env::consts::OS.to_string(),
            arch: std::env::consts::ARCH.to_string(),
            device: depthsense_model::device::describe(device),
        }
    }

    /// One line: "8 × Intel(R) Xeon(R) …, linux x86_64, device cpu".
    pub fn line(&self) -> String {
        format!(
            "{} × {}, {} {}, device {}",
            self.nproc,
            self.cpu_model.as_deref().unwrap_or("unknown CPU"),
            self.os,
            self.arch,
            self.device
        )
    }
}

/// Writes one experiment output file atomically; an error names the file.
pub(crate) fn save(path: &std::path::Path, bytes: &[u8]) -> Result<(), crate::ExperimentError> {
    depthsense_base::fsutil::write_atomic(path, bytes)
        .map_err(|e| depthsense_infer::NetError::io(path, e))?;
    Ok(())
}

/// `record` as pretty JSON at `json` with `doc` inside it (after the record's own fields:
/// `depthsense report` renders it), and `doc` as Markdown at `md`.
pub(crate) fn save_record<T: Serialize>(
    json: &std::path::Path,
    md: &std::path::Path,
    record: &T,
    doc: &depthsense_metrics::doc::Doc,
) -> Result<(), crate::ExperimentError> {
    let text = serde_json::to_string_pretty(&depthsense_metrics::doc::Documented {
        record,
        document: doc,
    })?;
    save(json, text.as_bytes())?;
    save(md, doc.to_markdown().as_bytes())
}

/// A signed number with a true minus sign ("−1.2", "+0.3").
pub(crate) fn signed(x: f64, prec: usize) -> String {
    if x < 0.0 {
        format!("−{:.prec$}", -x)
    } else {
        format!("+{x:.prec$}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_std_uses_n_minus_one() {
        let s = Stat::of(&[1.0, 2.0, 3.0, 4.0]).unwrap();
        assert_eq!(s.n, 4);
        assert!((s.mean - 2.5).abs() < 1e-12);
        // Σ(x − 2.5)² = 5, / 3.
        assert!((s.std.unwrap() - (5.0f64 / 3.0).sqrt()).abs() < 1e-12);
        let one = Stat::of(&[2.0, f64::NAN]).unwrap();
        assert_eq!((one.mean, one.std, one.n), (2.0, None, 1));
        assert!(Stat::of(&[]).is_none());
        assert_eq!(one.fmt(2), "2.00 ± –");
        assert_eq!(signed(-1.24, 1), "−1.2");
    }
}
