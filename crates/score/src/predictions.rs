//! `eval --predictions`: any method's depth maps on disk (one file per sample token, in the
//! training frame, SPEC §3) scored with exactly the protocol, caps, GT and conditions of
//! `eval --checkpoint` — both go through [`crate::score_image`].

use std::path::{Path, PathBuf};

use depthsense_base::fsutil::write_atomic;
use depthsense_dataset::{partition, read_depth, subsample, DataError, Dataset};
use depthsense_metrics::{EvalConfig, Evaluator, Report};
use depthsense_prep::layout::{IndexEntry, LIDAR_SPARSE_FILE};
use depthsense_progress::Progress;
use serde::{Deserialize, Serialize};

use crate::npy;
use crate::score_image;

/// Which samples to evaluate.
pub const HELD_OUT: &str = "held-out";

/// Samples of a split name (see [`EvalOptions::split`]).
pub fn select_split(ds: &Dataset, split: &str, every: usize) -> Result<Vec<IndexEntry>, DataError> {
    let v = if split == HELD_OUT {
        // The test scenes: never the validation scenes that selected the checkpoint.
        partition(ds, every)?.test
    } else {
        ds.split(split)
    };
    if v.is_empty() {
        return Err(DataError::EmptySplit {
            root: ds.root.clone(),
            split: split.to_string(),
            present: ds.split_names(),
        });
    }
    Ok(v)
}

/// What the scorer needs of a prepared sample: sparse GT and low-height mask.
#[derive(Debug, Clone)]
pub struct GroundTruth {
    pub width: usize,
    pub height: usize,
    pub sparse_m: Vec<f32>,
    /// Empty when the sample has no mask file.
    pub lowheight: Vec<bool>,
}

/// Read a sample's sparse GT and low-height mask (what `load_sample` reads with `eval_maps`).
pub fn load_ground_truth(ds: &Dataset, e: &IndexEntry) -> Result<GroundTruth, DataError> {
    let dir = ds.sample_dir(e);
    let gt = read_depth(&dir.join(LIDAR_SPARSE_FILE))?;
    let (w, h) = (gt.width as usize, gt.height as usize);
    let lowheight = depthsense_dataset::read_lowheight_mask(&dir, w, h)?;
    Ok(GroundTruth {
        width: w,
        height: h,
        sparse_m: gt.depth_m,
        lowheight,
    })
}

/// File formats of predictions on disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PredFormat {
    /// 16-bit PNG, depth × 256, 0 = no prediction (KITTI convention, SPEC §3).
    Png,
    /// NumPy float32 metres.
    Npy,
}

impl PredFormat {
    pub fn ext(self) -> &'static str {
        match self {
            PredFormat::Png => "png",
            PredFormat::Npy => "npy",
        }
    }
}

impl depthsense_base::words::Words for PredFormat {
    const WHAT: &'static str = "prediction format";
    const WORDS: &'static [(&'static str, Self)] = &[("png", Self::Png), ("npy", Self::Npy)];
}

/// The prediction file of a sample in `dir`: `<token>.npy`, `<token>.png`,
/// `<token>/depth.npy` or `<token>/depth.png` (first found, in that order).
pub fn find_prediction(dir: &Path, token: &str) -> Option<(PathBuf, PredFormat)> {
    [
        (dir.join(format!("{token}.npy")), PredFormat::Npy),
        (dir.join(format!("{token}.png")), PredFormat::Png),
        (dir.join(token).join("depth.npy"), PredFormat::Npy),
        (dir.join(token).join("depth.png"), PredFormat::Png),
    ]
    .into_iter()
    .find(|(p, _)| p.is_file())
}

/// Read one prediction file as (values in metres, width, height).
pub fn read_prediction(path: &Path, f: PredFormat) -> Result<(Vec<f32>, usize, usize), DataError> {
    match f {
        PredFormat::Png => {
            let m = read_depth(path)?;
            Ok((m.depth_m, m.width as usize, m.height as usize))
        }
        PredFormat::Npy => {
            let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
            let (v, h, w) = npy::decode(&bytes, path)?;
            Ok((v, w, h))
        }
    }
}

/// Write one prediction (metres, `w`x`h`) as `<dir>/<token>.<ext>`.
pub fn write_prediction(
    dir: &Path,
    token: &str,
    pred: &[f32],
    w: usize,
    h: usize,
    f: PredFormat,
) -> Result<PathBuf, DataError> {
    let p = dir.join(format!("{token}.{}", f.ext()));
    let bytes = match f {
        PredFormat::Npy => npy::encode_f32(pred, h, w),
        PredFormat::Png => {
            depthsense_nuscenes::depth_png::encode_png(&depthsense_nuscenes::depth_png::DepthMap {
                width: w as u32,
                height: h as u32,
                depth_m: pred.to_vec(),
            })?
        }
    };
    write_atomic(&p, &bytes).map_err(|e| DataError::io(&p, e))?;
    Ok(p)
}

/// `eval --predictions`: another method's depth maps, one per sample token.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PredictionsOptions {
    /// Folder of `<token>.png` / `<token>.npy` (see [`find_prediction`]).
    pub dir: PathBuf,
    pub data: PathBuf,
    pub split: String,
    pub val_every_scene: usize,
    pub eval: EvalConfig,
    pub max_samples: Option<usize>,
    /// Samples of the split without a prediction file: an error (false) or skipped and
    /// counted (true).
    pub allow_missing: bool,
}

/// What was scored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PredictionsSummary {
    pub scored: usize,
    pub png: usize,
    pub npy: usize,
    /// Tokens of the split without a prediction file.
    pub missing: Vec<String>,
}

/// `--predictions` must be a folder.
fn check_folder(dir: &Path) -> Result<(), DataError> {
    if !dir.is_dir() {
        return Err(DataError::NoPredictionsFolder {
            dir: dir.to_path_buf(),
        });
    }
    Ok(())
}

/// A prediction `(w, h)` (pixels) read from `path` must be in the frame of its ground truth.
fn check_frame(path: &Path, (w, h): (usize, usize), gt: &GroundTruth) -> Result<(), DataError> {
    if (w, h) != (gt.width, gt.height) {
        return Err(DataError::PredictionFrame {
            path: path.to_path_buf(),
            size: (w, h),
            frame: (gt.width, gt.height),
        });
    }
    Ok(())
}

/// Score prediction files with exactly the `eval --checkpoint` protocol ([`score_image`]).
pub fn run_eval_predictions(
    opts: &PredictionsOptions,
    progress: &Progress,
) -> Result<(Report, PredictionsSummary), DataError> {
    check_folder(&opts.dir)?;
    let ds = Dataset::open(&opts.data)?;
    let entries = subsample(
        &select_split(&ds, &opts.split, opts.val_every_scene)?,
        opts.max_samples,
    );
    let mut ev = Evaluator::new(opts.eval.clone())?;
    let mut sum = PredictionsSummary {
        scored: 0,
        png: 0,
        npy: 0,
        missing: vec![],
    };
    progress.set_length(entries.len() as u64);
    progress.println(format!(
        "{} samples of {} scored against {}",
        entries.len(),
        opts.data.display(),
        opts.dir.display()
    ));
    for e in &entries {
        progress.inc(1);
        let Some((path, fmt)) = find_prediction(&opts.dir, &e.sample_token) else {
            sum.missing.push(e.sample_token.clone());
            continue;
        };
        let gt = load_ground_truth(&ds, e)?;
        let (pred, w, h) = read_prediction(&path, fmt)?;
        check_frame(&path, (w, h), &gt)?;
        score_image(&mut ev, &gt.sparse_m, &gt.lowheight, &e.conditions, &pred)?;
        sum.scored += 1;
        match fmt {
            PredFormat::Png => sum.png += 1,
            PredFormat::Npy => sum.npy += 1,
        }
    }
    if !sum.missing.is_empty() && !opts.allow_missing {
        return Err(DataError::MissingPredictions {
            dir: opts.dir.clone(),
            missing: sum.missing.len(),
            samples: entries.len(),
            split: opts.split.clone(),
            first: sum.missing[0].clone(),
        });
    }
    Ok((ev.finish(), sum))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--predictions` that is not a folder, and a prediction of another frame than its ground
    /// truth, are refused with the folder, the file and both sizes.
    #[test]
    fn a_missing_folder_and_a_prediction_of_another_frame_are_named() {
        let d = tempfile::tempdir().unwrap();
        assert!(check_folder(d.path()).is_ok());
        let missing = d.path().join("preds");
        let e = check_folder(&missing).unwrap_err();
        assert!(matches!(&e, DataError::NoPredictionsFolder { dir } if dir == &missing));
        assert_eq!(
            e.to_string(),
            format!(
                "data: {}: no such folder; --predictions takes a folder of <sample token>.png \
                 (16-bit, depth×256) or .npy (float32 metres) files, as `depthsense predict \
                 --data` writes",
                missing.display()
            )
        );
        let gt = GroundTruth {
            width: 8,
            height: 4,
            sparse_m: vec![0.0; 32],
            lowheight: vec![],
        };
        let p = Path::new("preds/tok.npy");
        assert!(check_frame(p, (8, 4), &gt).is_ok());
        let e = check_frame(p, (4, 8), &gt).unwrap_err();
        assert!(matches!(
            e,
            DataError::PredictionFrame {
                size: (4, 8),
                frame: (8, 4),
                ..
            }
        ));
    }
}
