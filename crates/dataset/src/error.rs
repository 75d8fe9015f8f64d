//! The error of the torch-free data layer: each names the file, record or setting at fault.
//! `depthsense_infer::NetError` carries it whole (`NetError::Dataset`), messages unchanged.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use depthsense_nuscenes::depth_png::DepthPngError;
use depthsense_nuscenes::NuError;
use depthsense_prep::layout::META_FILE;
use depthsense_prep::radar_points::RadarPointsError;
use depthsense_prep::PrepError;

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: cannot parse: {reason}", .path.display())]
    Parse { path: PathBuf, reason: String },
    #[error(transparent)]
    Metrics(#[from] depthsense_metrics::MetricsError),
    #[error("{} already holds {what}; nothing was changed: {advice}", .dir.display())]
    OutputExists {
        dir: PathBuf,
        what: String,
        advice: String,
    },

    // --- The prepared folder: its index and splits ---
    /// `--data` is not a prepared folder (no `index.json`); what it is instead says what to do.
    #[error("{}", no_index_text(.root, .found))]
    NoIndex { root: String, found: NotPrepared },
    /// `--sample` (or the Python module's `read_sample`) is not one prepared sample's folder
    /// (no `meta.json`); what it is instead says what to pass.
    #[error("{}", not_a_sample_text(.dir, .found))]
    NotASample { dir: String, found: SampleFolder },
    /// A prepared folder's `index.json` (`index`) that lists no sample.
    #[error(
        "data: {} lists no samples: run `depthsense prepare` first",
        .index.display()
    )]
    EmptyIndex { index: PathBuf },
    /// A partition of the prepared folder `data` (made as `method` says) without training or
    /// without validation samples, which a training run needs both of.
    #[error(
        "data: {}: {train} training and {val} validation samples ({method}): need both",
        .data.display()
    )]
    NoTrainOrVal {
        data: PathBuf,
        train: usize,
        val: usize,
        method: String,
    },
    /// A prepared folder without split lists whose `scenes` scenes are too few (3 at least) for
    /// a train / validation / test partition by scene.
    #[error(
        "data: {}: need at least 3 scenes for train / validation / test, found {scenes}",
        .root.display()
    )]
    TooFewScenes { root: PathBuf, scenes: usize },
    /// A split (`split`, or `held-out`: the test scenes) of the prepared folder `root` without
    /// samples; `present` are the split names its index has.
    #[error(
        "data: {}: split {split:?} has no samples (splits present: {present:?})",
        .root.display()
    )]
    EmptySplit {
        root: PathBuf,
        split: String,
        present: BTreeSet<String>,
    },

    // --- A prepared sample and its files (those that make it unreadable to the loader:
    // `DataError::unreadable_reason`) ---
    /// A prepared sample's folder without its `meta.json` (written last by `prepare`).
    #[error("data: {}: incomplete sample directory (no {META_FILE})", .dir.display())]
    IncompleteSample { dir: PathBuf },
    /// A prepared sample's map (`path`) whose size is not its image's.
    #[error(
        "data: {}: map is {}x{} but the image is {}x{}",
        .path.display(), .size.0, .size.1, .image.0, .image.1
    )]
    MapSize {
        path: PathBuf,
        /// (width, height) of the map.
        size: (usize, usize),
        /// (width, height) of the image.
        image: (usize, usize),
    },
    /// A sample prepared without the accumulated lidar (`meta` records `--lidar-sweeps 0`)
    /// where `needs` requires it.
    #[error(
        "data: {}: prepared with --lidar-sweeps 0; {needs} need the accumulated lidar of \
         `depthsense prepare --lidar-sweeps K` with K > 0 (SPEC §4–5)",
        .meta.display()
    )]
    NotAccumulated { meta: PathBuf, needs: &'static str },
    /// A sample's accumulated lidar map (`path`) missing where `needs` requires it.
    #[error(
        "data: {}: missing; {needs} need the accumulated lidar map of `depthsense prepare \
         --lidar-sweeps K` (K > 0, SPEC §5)",
        .path.display()
    )]
    NoAccumulatedLidar { path: PathBuf, needs: &'static str },
    /// A sample without the lidar ground truth that `needs` requires.
    #[error("data: {}: no lidar GT ({needs} needs it)", .dir.display())]
    NoGroundTruth { dir: PathBuf, needs: &'static str },
    /// A 16-bit depth PNG (a map, a confidence map, a prediction) that cannot be decoded or
    /// encoded.
    #[error("data: {0}")]
    Png(#[from] DepthPngError),
    /// A sample's low-height mask (`path`) with `pixels` pixels where its image has `expected`.
    #[error(
        "data: {}: mask has {pixels} pixels, expected {expected}",
        .path.display()
    )]
    MaskSize {
        path: PathBuf,
        pixels: usize,
        expected: usize,
    },
    /// A sample's MER map (`path`) missing: `mer apply` has not been run on its folder.
    #[error(
        "data: {}: missing; radar input `mer` needs `depthsense mer apply --checkpoint \
         PDA.safetensors --data <prepared>` first (SPEC §5)",
        .path.display()
    )]
    NoMerMap { path: PathBuf },
    /// A sample's MER confidence map (`conf`) of another size than its MER depth map (`depth`).
    #[error(
        "data: {}: {}x{} but {} is {}x{}",
        .conf.display(), .conf_size.0, .conf_size.1,
        .depth.display(), .depth_size.0, .depth_size.1
    )]
    MerMapSizes {
        conf: PathBuf,
        /// (width, height) of the confidence map.
        conf_size: (u32, u32),
        depth: PathBuf,
        /// (width, height) of the depth map.
        depth_size: (u32, u32),
    },
    /// The radar points of sample `sample` (its `radar_points.bin`), needed to rebuild its
    /// radar maps for a sensor failure, that cannot be read.
    #[error("data: sample {sample}: {source}")]
    SampleRadarPoints {
        sample: String,
        #[source]
        source: RadarPointsError,
    },
    /// A sample's radar points that cannot be read where the oracle radar is rebuilt from them.
    #[error("data: {source} (the oracle radar is rebuilt from each sample's radar points)")]
    OracleRadarPoints {
        #[source]
        source: RadarPointsError,
    },
    /// A sample (folder `dir`) whose radar map `map` (`radar`, `height`) or MER maps are not
    /// the size of its lidar ground truth (`mer report`).
    #[error(
        "data: {}: {map} / MER maps and the lidar GT differ in size",
        .dir.display()
    )]
    CoverageMapSizes { dir: PathBuf, map: &'static str },

    // --- What the loader is asked to do (training and evaluation options) ---
    /// The oracle radar asked for together with sensor failures or MER inputs, which are
    /// built from the maps it replaces.
    #[error(
        "configuration: the oracle radar is not combined with sensor failures or MER inputs \
         (it replaces the maps those are built from): drop one of them"
    )]
    OracleRadarCombined,
    /// A calibration perturbation asked for with a model fed MER inputs.
    #[error(
        "configuration: a calibration perturbation of MER inputs would need `mer apply` on \
         the perturbed maps: not supported (use a raw / height-extended model)"
    )]
    MerPerturbation,
    /// `--drop-beyond-m` that is not a positive number of metres.
    #[error("configuration: --drop-beyond-m must be a positive number of metres, got {metres}")]
    DropBeyondNotPositive { metres: f64 },
    /// A calibration perturbation whose magnitude is negative or not a number.
    #[error("configuration: perturbation magnitude must be a non-negative number, got {amount}")]
    NegativePerturbation { amount: f64 },
    /// One `--exclude` word (`word`, `CONDITION=FRACTION`) that cannot be read, and why.
    #[error("configuration: --exclude {word:?}: {}", .fault.text())]
    BadExclusion { word: String, fault: ExclusionFault },

    // --- Batches ---
    /// A batch size of 0.
    #[error("configuration: batch size must be at least 1")]
    ZeroBatchSize,
    /// A batch of `batch` samples with fewer samples than the `ranks` data-parallel ranks
    /// that share it.
    #[error("configuration: a batch of {batch} sample(s) cannot be shared by {ranks} ranks")]
    BatchNotShared { batch: usize, ranks: usize },
    /// A sample (token `sample`) whose frame or radar channels are not its batch's.
    #[error(
        "data: sample {sample} is {}x{} with {} radar channels, but the batch is {}x{} with {}",
        .shape.0, .shape.1, .shape.2, .batch.0, .batch.1, .batch.2
    )]
    BatchMismatch {
        sample: String,
        /// (width, height, radar channels) of the sample.
        shape: (usize, usize, usize),
        /// (width, height, radar channels) of the batch.
        batch: (usize, usize, usize),
    },

    // --- A network input (predict, the Python module): prepared, from a token, raw files ---
    /// An input (`input`) without MER maps for a model that takes MER radar.
    #[error(
        "configuration: {input}: the model takes MER radar (SPEC §5) but the input has no MER \
         maps: run `depthsense mer apply` on the prepared data or pass --mer-checkpoint"
    )]
    InputWithoutMer { input: String },
    /// An input (`input`) whose radar planes do not cover its image's pixels.
    #[error(
        "data: {input}: radar maps do not have the image's {}x{} pixels",
        .image.0, .image.1
    )]
    RadarPlanesSize {
        input: String,
        /// (width, height) of the image.
        image: (usize, usize),
    },
    /// A nuScenes dataroot (its tables) or radar `.pcd` file that cannot be read.
    #[error("data: {0}")]
    NuScenes(#[from] NuError),
    /// A sample token (`token`) that the tables of `dataroot`/`version` do not have.
    #[error(
        "data: {}/{version}: no sample with token {token}",
        .dataroot.display()
    )]
    NoSuchToken {
        dataroot: PathBuf,
        version: String,
        token: String,
    },
    /// `prepare`'s computation of the maps of sample `token` that failed.
    #[error("data: sample {token}: {source}")]
    TokenPrepare {
        token: String,
        #[source]
        source: Box<PrepError>,
    },
    /// A camera image that is not of the training frame's size after `prepare`'s crop
    /// (`sample`: the token it was computed for, if any).
    #[error("{}", frame_image_text(.sample.as_deref()))]
    FrameImage { sample: Option<String> },
    /// A calibration JSON (`path`) that cannot be read.
    #[error("data: {source}")]
    Calibration {
        path: PathBuf,
        #[source]
        source: Box<PrepError>,
    },
    /// A radar file (`file`, by name) that the calibration `calibration` has no entry for;
    /// `entries` are the file names it has.
    #[error(
        "data: {}: no cam_from_radar entry for radar file {file:?} (entries: {entries:?}); \
         write the calibration with `depthsense calibration`, which lists every sweep",
        .calibration.display()
    )]
    NoCalibrationEntry {
        calibration: PathBuf,
        file: String,
        entries: Vec<String>,
    },
    /// A camera image (`input`) that is not a nuScenes CAM_FRONT image (1600x900).
    #[error(
        "data: {input}: image is {}x{}; a nuScenes CAM_FRONT image is 1600x900",
        .size.0, .size.1
    )]
    NotCamFront {
        input: String,
        /// (width, height) of the image.
        size: (u32, u32),
    },

    // --- A folder of another method's predictions (eval --predictions) ---
    /// `--predictions` (`dir`) that is not a folder.
    #[error(
        "data: {}: no such folder; --predictions takes a folder of <sample token>.png (16-bit, \
         depth×256) or .npy (float32 metres) files, as `depthsense predict --data` writes",
        .dir.display()
    )]
    NoPredictionsFolder { dir: PathBuf },
    /// A prediction (`path`) that is not in the frame of its ground truth.
    #[error(
        "data: {}: prediction is {}x{} but the ground truth of the training frame is {}x{} \
         (SPEC §3: predictions must be in the 800x350 frame `prepare` writes)",
        .path.display(), .size.0, .size.1, .frame.0, .frame.1
    )]
    PredictionFrame {
        path: PathBuf,
        /// (width, height) of the prediction.
        size: (usize, usize),
        /// (width, height) of the ground truth.
        frame: (usize, usize),
    },
    /// `missing` of the `samples` samples of split `split` without a prediction in `dir`
    /// (`first`: the token of the first), where `--allow-missing` was not passed.
    #[error(
        "data: {}: {missing} of {samples} samples of split {split:?} have no prediction (e.g. \
         {first}.png / .npy); pass --allow-missing to score the others",
        .dir.display()
    )]
    MissingPredictions {
        dir: PathBuf,
        missing: usize,
        samples: usize,
        split: String,
        first: String,
    },

    // --- Threads, encoding, and the samples the loader could not read ---
    /// A worker thread (`what`: the loader's) that the system would not start.
    #[error("cannot start {what}: {source}")]
    ThreadStart {
        what: &'static str,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A file whose bytes cannot be encoded before it is written (a JSON record, a PNG).
    #[error("{}: cannot encode: {source}", .path.display())]
    Encode {
        path: PathBuf,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// Prepared samples that cannot be read, every one with its reason (the loader reads on
    /// past them, so that `eval` and `predict` name them all at once), and how to rebuild them.
    #[error("{}", unreadable_text(.root, .samples))]
    Unreadable {
        /// The prepared folder.
        root: String,
        /// (sample token, what is wrong), in the order they were met.
        samples: Vec<(String, String)>,
    },
}

/// What a folder without `index.json` holds.
#[derive(Debug, Clone, PartialEq)]
pub enum NotPrepared {
    /// No such folder; prepared folders beside where it would be.
    Missing { prepared_siblings: Vec<String> },
    /// Shard indexes of a sharded `prepare` not merged yet.
    Shards(Vec<String>),
    /// A nuScenes dataroot (its version folders).
    Dataroot(Vec<String>),
    /// Anything else.
    Other,
}

/// What a folder passed as one sample (without `meta.json`) is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleFolder {
    /// A prepared folder (it holds `index.json`): its samples are its sub-folders.
    Prepared,
    /// Some other folder.
    Other,
    /// No such folder.
    Missing,
}

/// What is wrong with one `--exclude` word (`CONDITION=FRACTION`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExclusionFault {
    /// No `=`.
    NoFraction,
    /// A condition other than day, night or rain.
    UnknownCondition,
    /// A fraction that is not a number.
    NotANumber,
    /// A fraction outside [0, 1].
    OutOfRange,
}

impl ExclusionFault {
    fn text(self) -> &'static str {
        match self {
            Self::NoFraction => "expected CONDITION=FRACTION, e.g. night=1.0",
            Self::UnknownCondition => "condition must be day, night or rain",
            Self::NotANumber => "fraction must be a number",
            Self::OutOfRange => "fraction must be within [0, 1]",
        }
    }
}

fn frame_image_text(sample: Option<&str>) -> String {
    match sample {
        Some(token) => format!("data: sample {token}: image has the wrong size"),
        None => "data: frame has the wrong size".into(),
    }
}

fn not_a_sample_text(d: &str, found: &SampleFolder) -> String {
    let takes = "--sample takes one PREPARED/<sample token> folder written by `depthsense prepare`";
    match found {
        SampleFolder::Prepared => format!(
            "{d} is a prepared folder, not one sample: pass --sample {d}/<sample token> \
             for one of its samples, or --data {d} for a split of them"
        ),
        SampleFolder::Other => {
            format!("{d}: not a prepared sample folder (no {META_FILE}); {takes}")
        }
        SampleFolder::Missing => format!("{d}: no such folder; {takes}"),
    }
}

fn no_index_text(root: &str, found: &NotPrepared) -> String {
    let run_prepare =
        "run `depthsense prepare --dataroot DATAROOT --version VERSION --out FOLDER` \
                       and pass that FOLDER";
    match found {
        NotPrepared::Missing { prepared_siblings } if !prepared_siblings.is_empty() => format!(
            "{root}: no such folder; prepared folders beside it: {} (or {run_prepare})",
            prepared_siblings.join(", ")
        ),
        NotPrepared::Missing { .. } => {
            format!("{root}: no such folder; --data takes a folder written by `depthsense prepare`: {run_prepare}")
        }
        NotPrepared::Shards(shards) => format!(
            "{root} holds the shard indexes of a sharded prepare ({}) but no index.json: merge \
             them first with `depthsense index merge {root}`",
            shards.join(", ")
        ),
        NotPrepared::Dataroot(versions) => format!(
            "{root} is a nuScenes dataroot ({}), not a prepared folder: run `depthsense prepare \
             --dataroot {root} --version {} --out FOLDER` and pass that FOLDER",
            versions.join(", "),
            versions.first().map_or("VERSION", String::as_str)
        ),
        NotPrepared::Other => {
            format!("{root}: no index.json, so not a prepared folder: {run_prepare}")
        }
    }
}

impl DataError {
    /// One error for several: every [`DataError::Unreadable`] merged into one, unless another
    /// kind is among them (then the first of those). `None` for none.
    pub fn merged(errors: Vec<DataError>) -> Option<DataError> {
        let mut root = None;
        let mut samples = vec![];
        for e in errors {
            match e {
                DataError::Unreadable {
                    root: r,
                    samples: s,
                } => {
                    root.get_or_insert(r);
                    samples.extend(s);
                }
                other => return Some(other),
            }
        }
        root.map(|root| DataError::Unreadable { root, samples })
    }

    /// Why a prepared sample cannot be read, as [`DataError::Unreadable`] lists it, when this
    /// error is a failure of the sample's own files (missing, truncated, corrupt, of another
    /// size: what `prepare --verify` or `mer apply` rebuilds); the message without its `data: `
    /// prefix. `None` for any other error (a refused option, a batch, …).
    pub fn unreadable_reason(&self) -> Option<String> {
        match self {
            Self::Io { .. } | Self::Parse { .. } => Some(self.to_string()),
            Self::IncompleteSample { .. }
            | Self::MapSize { .. }
            | Self::Png(_)
            | Self::MaskSize { .. }
            | Self::NoMerMap { .. }
            | Self::MerMapSizes { .. }
            | Self::SampleRadarPoints { .. }
            | Self::OracleRadarPoints { .. } => {
                let text = self.to_string();
                Some(text.strip_prefix("data: ").unwrap_or(&text).to_string())
            }
            _ => None,
        }
    }

    /// `what` (threads) cannot be started (`source` says why).
    pub fn thread_start(
        what: &'static str,
        source: impl std::error::Error + Send + Sync + 'static,
    ) -> Self {
        Self::ThreadStart {
            what,
            source: Box::new(source),
        }
    }

    /// `path`'s bytes cannot be encoded (`source` says why).
    pub fn encode(path: &Path, source: impl std::error::Error + Send + Sync + 'static) -> Self {
        Self::Encode {
            path: path.to_path_buf(),
            source: Box::new(source),
        }
    }

    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

fn unreadable_text(root: &str, samples: &[(String, String)]) -> String {
    let mut s = format!(
        "{} prepared sample(s) of {root} cannot be read:",
        samples.len()
    );
    for (token, why) in samples {
        // The reason names the sample's file (and so its token) when it has one.
        if why.contains(token.as_str()) {
            s += &format!("\n  {why}");
        } else {
            s += &format!("\n  {token}: {why}");
        }
    }
    let mer = samples.iter().all(|(_, why)| why.contains("radar_mer_"));
    s += &if mer {
        format!(
            "\nthe MER maps come from `depthsense mer apply --data {root} --checkpoint PDA.safetensors` \
             (docs/guide/mer.md); a model trained with --radar-input mer needs them"
        )
    } else {
        format!(
            "\nto rebuild them, rerun the `depthsense prepare` command that wrote {root} with \
             --verify added: it re-reads every sample and prepares the broken ones again \
             (docs/guide/prepare.md, \"Checking a prepared folder\")"
        )
    };
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::error::Error;

    /// The index, split and prediction-folder refusals read as they always have.
    #[test]
    fn index_split_and_prediction_messages() {
        let present: BTreeSet<String> = ["train".into(), "val".into()].into();
        let e = DataError::EmptySplit {
            root: "toy".into(),
            split: "test".into(),
            present,
        };
        assert_eq!(
            e.to_string(),
            "data: toy: split \"test\" has no samples (splits present: {\"train\", \"val\"})"
        );
        let e = DataError::MissingPredictions {
            dir: "preds".into(),
            missing: 2,
            samples: 5,
            split: "all".into(),
            first: "tok".into(),
        };
        assert_eq!(
            e.to_string(),
            "data: preds: 2 of 5 samples of split \"all\" have no prediction (e.g. tok.png / \
             .npy); pass --allow-missing to score the others"
        );
        let e = DataError::PredictionFrame {
            path: "preds/tok.npy".into(),
            size: (10, 4),
            frame: (800, 350),
        };
        assert_eq!(
            e.to_string(),
            "data: preds/tok.npy: prediction is 10x4 but the ground truth of the training frame \
             is 800x350 (SPEC §3: predictions must be in the 800x350 frame `prepare` writes)"
        );
        let e = DataError::CoverageMapSizes {
            dir: "toy/tok".into(),
            map: "height",
        };
        assert_eq!(
            e.to_string(),
            "data: toy/tok: height / MER maps and the lidar GT differ in size"
        );
    }

    /// The batch and loading-option refusals keep their `configuration: ` / `data: ` words.
    #[test]
    fn batch_and_option_messages() {
        let cases = [
            (
                DataError::BatchMismatch {
                    sample: "tok".into(),
                    shape: (8, 4, 2),
                    batch: (8, 4, 1),
                },
                "data: sample tok is 8x4 with 2 radar channels, but the batch is 8x4 with 1",
            ),
            (
                DataError::ZeroBatchSize,
                "configuration: batch size must be at least 1",
            ),
            (
                DataError::BatchNotShared { batch: 3, ranks: 4 },
                "configuration: a batch of 3 sample(s) cannot be shared by 4 ranks",
            ),
            (
                DataError::OracleRadarCombined,
                "configuration: the oracle radar is not combined with sensor failures or MER \
                 inputs (it replaces the maps those are built from): drop one of them",
            ),
            (
                DataError::MerPerturbation,
                "configuration: a calibration perturbation of MER inputs would need `mer apply` \
                 on the perturbed maps: not supported (use a raw / height-extended model)",
            ),
            (
                DataError::DropBeyondNotPositive { metres: -2.5 },
                "configuration: --drop-beyond-m must be a positive number of metres, got -2.5",
            ),
            (
                DataError::NegativePerturbation { amount: -1.0 },
                "configuration: perturbation magnitude must be a non-negative number, got -1",
            ),
            (
                DataError::BadExclusion {
                    word: "fog=1".into(),
                    fault: ExclusionFault::UnknownCondition,
                },
                "configuration: --exclude \"fog=1\": condition must be day, night or rain",
            ),
        ];
        for (e, text) in cases {
            assert_eq!(e.to_string(), text);
        }
    }

    /// The refusals of a network input (prepared, token, raw files) read as they always have.
    #[test]
    fn network_input_messages() {
        let cases = [
            (
                DataError::InputWithoutMer {
                    input: "tok".into(),
                },
                "configuration: tok: the model takes MER radar (SPEC §5) but the input has no \
                 MER maps: run `depthsense mer apply` on the prepared data or pass \
                 --mer-checkpoint",
            ),
            (
                DataError::RadarPlanesSize {
                    input: "tok".into(),
                    image: (8, 4),
                },
                "data: tok: radar maps do not have the image's 8x4 pixels",
            ),
            (
                DataError::NoSuchToken {
                    dataroot: "nu".into(),
                    version: "v1.0-mini".into(),
                    token: "abc".into(),
                },
                "data: nu/v1.0-mini: no sample with token abc",
            ),
            (
                DataError::FrameImage {
                    sample: Some("abc".into()),
                },
                "data: sample abc: image has the wrong size",
            ),
            (
                DataError::FrameImage { sample: None },
                "data: frame has the wrong size",
            ),
            (
                DataError::NoCalibrationEntry {
                    calibration: "calib.json".into(),
                    file: "b.pcd".into(),
                    entries: vec!["a.pcd".into()],
                },
                "data: calib.json: no cam_from_radar entry for radar file \"b.pcd\" (entries: \
                 [\"a.pcd\"]); write the calibration with `depthsense calibration`, which lists \
                 every sweep",
            ),
            (
                DataError::NotCamFront {
                    input: "cam.jpg".into(),
                    size: (640, 480),
                },
                "data: cam.jpg: image is 640x480; a nuScenes CAM_FRONT image is 1600x900",
            ),
        ];
        for (e, text) in cases {
            assert_eq!(e.to_string(), text);
        }
    }

    /// An error of another layer keeps its message behind `data: ` and stays the cause.
    #[test]
    fn wrapped_errors_keep_their_message_and_cause() {
        let png = DepthPngError::Decode {
            path: "s/radar.png".into(),
            reason: "truncated".into(),
        };
        let e = DataError::from(png);
        assert_eq!(
            e.to_string(),
            "data: s/radar.png: cannot decode PNG: truncated"
        );
        assert!(e.source().is_some());
        let prep = || Box::new(PrepError::UnknownSplit("x".into()));
        let e = DataError::TokenPrepare {
            token: "abc".into(),
            source: prep(),
        };
        assert_eq!(e.to_string(), format!("data: sample abc: {}", prep()));
        assert!(e.source().is_some());
        let e = DataError::Calibration {
            path: "calib.json".into(),
            source: prep(),
        };
        assert_eq!(e.to_string(), format!("data: {}", prep()));
        let missing = || RadarPointsError::Missing {
            path: "s/radar_points.bin".into(),
        };
        let e = DataError::SampleRadarPoints {
            sample: "tok".into(),
            source: missing(),
        };
        assert_eq!(e.to_string(), format!("data: sample tok: {}", missing()));
        let e = DataError::OracleRadarPoints { source: missing() };
        assert_eq!(
            e.to_string(),
            format!(
                "data: {} (the oracle radar is rebuilt from each sample's radar points)",
                missing()
            )
        );
    }

    /// The failures of a sample's files are unreadable samples, named without `data: `; a
    /// refused option or a batch is not.
    #[test]
    fn a_sample_file_failure_is_an_unreadable_reason() {
        let reason = |e: DataError| e.unreadable_reason();
        assert_eq!(
            reason(DataError::IncompleteSample {
                dir: "toy/s0".into()
            }),
            Some("toy/s0: incomplete sample directory (no meta.json)".into())
        );
        assert_eq!(
            reason(DataError::MaskSize {
                path: "toy/s0/lowheight_mask.png".into(),
                pixels: 4,
                expected: 8,
            }),
            Some("toy/s0/lowheight_mask.png: mask has 4 pixels, expected 8".into())
        );
        assert_eq!(
            reason(DataError::NoMerMap {
                path: "toy/s0/radar_mer_depth.png".into()
            }),
            Some(
                "toy/s0/radar_mer_depth.png: missing; radar input `mer` needs `depthsense mer \
                 apply --checkpoint PDA.safetensors --data <prepared>` first (SPEC §5)"
                    .into()
            )
        );
        assert_eq!(
            reason(DataError::MerMapSizes {
                conf: "s/c.png".into(),
                conf_size: (2, 2),
                depth: "s/d.png".into(),
                depth_size: (4, 2),
            }),
            Some("s/c.png: 2x2 but s/d.png is 4x2".into())
        );
        let io = DataError::io(Path::new("s/image.png"), std::io::Error::other("gone"));
        assert_eq!(reason(io), Some("s/image.png: gone".into()));
        assert_eq!(reason(DataError::ZeroBatchSize), None);
        assert_eq!(reason(DataError::OracleRadarCombined), None);
        let batch = DataError::BatchMismatch {
            sample: "tok".into(),
            shape: (1, 1, 1),
            batch: (2, 2, 2),
        };
        assert_eq!(reason(batch), None);
    }
}
