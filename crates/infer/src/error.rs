//! The training stack's error: each names the file, record or setting at fault. The data
//! layer's [`depthsense_dataset::DataError`] comes in whole (`Dataset`), with its messages.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum NetError {
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: cannot parse: {reason}", .path.display())]
    Parse { path: PathBuf, reason: String },
    /// A tensor file (an optimiser state) that libtorch cannot write or read.
    #[error("{}: {source}", .path.display())]
    TensorFile {
        path: PathBuf,
        #[source]
        source: tch::TchError,
    },
    /// A JSON record (a run's config, an experiment's results) that cannot be serialised.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// Data-parallel training: the process group, a collective, the launcher's environment.
    #[error(transparent)]
    Dist(#[from] depthsense_dist::DistError),
    /// A request that the model does not serve (a radar input it does not read, a variant
    /// word it does not know): the request is at fault, not the model.
    #[error("configuration: {0}")]
    Request(depthsense_config::ConfigError),
    /// `eval --radar-drop` outside [0, 1].
    #[error("configuration: --radar-drop must be within [0, 1], got {0}")]
    RadarDropNotAFraction(f64),
    /// `explain` of a network or an input it cannot explain.
    #[error("configuration: {0}")]
    Explain(#[from] depthsense_config::refusal::ExplainRefusal),
    /// `mer apply` onto MER maps of another PDA checkpoint, without `--force`.
    #[error(
        "configuration: {}: MER maps of another PDA model ({there}, fnv64 {there_fnv64}) are \
         there; pass --force to replace them with {}",
        .record.display(),
        .requested.display()
    )]
    OtherMerMaps {
        /// The maps' record (`mer.json`).
        record: PathBuf,
        there: String,
        there_fnv64: String,
        requested: PathBuf,
    },
    /// One batch of the PDA network holding frames of two sizes: (width, height) of the first
    /// frame and of the first that differs.
    #[error(
        "data: MER grids differ within a batch ({}x{} vs {}x{}): frames of one size are needed",
        .other.0, .other.1, .first.0, .first.1
    )]
    MerGridsDiffer {
        first: (usize, usize),
        other: (usize, usize),
    },
    /// No optimiser state beside a checkpoint is at the checkpoint's iteration: the state
    /// file and its previous generation at theirs (`None`: absent).
    #[error(
        "data: {} is {} and {} {}, but {} is at iteration {iteration}: no optimiser state \
         belongs to the checkpoint",
        .state.display(), at_iteration(*.state_at), .previous.display(),
        at_iteration(*.previous_at), .checkpoint.display()
    )]
    NoMatchingOptimiserState {
        state: PathBuf,
        state_at: Option<u64>,
        previous: PathBuf,
        previous_at: Option<u64>,
        checkpoint: PathBuf,
        iteration: u64,
    },
    /// A training run's options refused: by themselves, against the data or the ranks, or
    /// against the checkpoint they continue.
    #[error("configuration: {0}")]
    Refused(#[from] depthsense_config::refusal::TrainingRefusal),
    #[error(transparent)]
    Model(#[from] depthsense_model::ModelError),
    #[error(transparent)]
    Metrics(#[from] depthsense_metrics::MetricsError),
    #[error(transparent)]
    Viz(#[from] depthsense_viz::VizError),
    #[error("libtorch: {0}")]
    Torch(#[from] tch::TchError),
    /// A 16-bit depth PNG that cannot be written or read back.
    #[error("data: {0}")]
    DepthPng(#[from] depthsense_nuscenes::depth_png::DepthPngError),
    /// A nuScenes table or sensor file (`predict --token`, `--image`).
    #[error("data: {0}")]
    Nuscenes(#[from] depthsense_nuscenes::NuError),
    /// `prepare`'s computation or one of its files (a calibration JSON).
    #[error("data: {0}")]
    Prep(#[from] depthsense_prep::error::PrepError),
    #[error(
        "non-finite loss ({loss}) at epoch {epoch}, iteration {iteration}: training stopped; \
         the last good checkpoint is kept at {kept}"
    )]
    NonFiniteLoss {
        loss: f64,
        epoch: u64,
        iteration: u64,
        kept: String,
    },
    #[error(transparent)]
    Lock(#[from] depthsense_base::lock::LockError),
    /// The data layer's errors (prepared folders, the loader, unreadable samples), with their
    /// own messages.
    #[error(transparent)]
    Dataset(#[from] depthsense_dataset::DataError),
    /// A SyncBatchNorm collective inside a forward (kept by the hook, reported after it).
    #[error("sync batch norm: {0}")]
    SyncBatchNorm(#[source] depthsense_dist::DistError),
    /// `--check-replicas`: this rank's weights are no longer rank 0's.
    #[error(
        "rank {rank}: the model differs from rank 0's after iteration {iteration} \
         (max |Δ| = {max_abs_diff:e})"
    )]
    ReplicasDiffer {
        rank: usize,
        iteration: u64,
        max_abs_diff: f64,
    },
    /// The network's decoded output has not the shape its input asks for (a bug, not a bad
    /// input).
    #[error("{what} has shape {got:?}, expected {want:?}")]
    OutputShape {
        what: &'static str,
        got: Vec<i64>,
        want: Vec<i64>,
    },
    /// Depths decoded at the valid ground-truth pixels, not one per pixel.
    #[error("decoded {got} depths at {want} ground-truth pixels")]
    DecodedAtGroundTruth { got: usize, want: i64 },
    /// A sample's ground truth has not the batch's pixel count.
    #[error("sample {sample}: ground truth of {got} pixels, expected {want}")]
    GroundTruthSize {
        sample: String,
        got: usize,
        want: usize,
    },
    /// A worker thread (`thread` names it) panicked; its work is lost.
    #[error("the {thread} thread panicked")]
    ThreadPanicked { thread: &'static str },
    /// Data-parallel training: gradients averaged before the network's gradient buckets were
    /// attached (a bug of the caller).
    #[error("distributed: gradients synchronised before attach")]
    GradientsNotAttached,
}

fn at_iteration(i: Option<u64>) -> String {
    i.map_or("absent".to_string(), |i| format!("at iteration {i}"))
}

impl NetError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// An unknown preset or `--set` key, or a config no network can be built with.
impl From<depthsense_config::ConfigError> for NetError {
    fn from(e: depthsense_config::ConfigError) -> Self {
        use depthsense_config::ConfigError as C;
        match e {
            // a mismatch between a request and the model, not an invalid model (same message
            // as when the trainer owned the rule)
            C::RadarChannels { .. } | C::UnknownVariant(_) => NetError::Request(e),
            e => NetError::Model(e.into()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The typed variants read as the strings they replaced did.
    #[test]
    fn typed_variants_keep_their_messages() {
        let e = NetError::ReplicasDiffer {
            rank: 1,
            iteration: 7,
            max_abs_diff: 0.5,
        };
        assert_eq!(
            e.to_string(),
            "rank 1: the model differs from rank 0's after iteration 7 (max |Δ| = 5e-1)"
        );
        let e = NetError::SyncBatchNorm(depthsense_dist::DistError::Collective("timeout".into()));
        assert_eq!(e.to_string(), "sync batch norm: timeout");
        let e = NetError::from(depthsense_dist::DistError::from(
            depthsense_dist::launch::LaunchError::NoWorkers,
        ));
        assert_eq!(e.to_string(), "configuration: --nproc must be at least 1");
    }

    /// The variants that replaced `Other(String)` read as the strings did.
    #[test]
    fn checks_and_stages_read_as_before() {
        let e = NetError::OutputShape {
            what: "decoded prediction",
            got: vec![2, 1, 4],
            want: vec![2, 1, 4, 8],
        };
        assert_eq!(
            e.to_string(),
            "decoded prediction has shape [2, 1, 4], expected [2, 1, 4, 8]"
        );
        let e = NetError::DecodedAtGroundTruth { got: 5, want: 6 };
        assert_eq!(e.to_string(), "decoded 5 depths at 6 ground-truth pixels");
        let e = NetError::GroundTruthSize {
            sample: "tok".into(),
            got: 3,
            want: 32,
        };
        assert_eq!(
            e.to_string(),
            "sample tok: ground truth of 3 pixels, expected 32"
        );
        let e = NetError::ThreadPanicked {
            thread: "MER writer",
        };
        assert_eq!(e.to_string(), "the MER writer thread panicked");
        assert_eq!(
            NetError::GradientsNotAttached.to_string(),
            "distributed: gradients synchronised before attach"
        );
        let e = NetError::MerGridsDiffer {
            first: (100, 44),
            other: (50, 22),
        };
        assert_eq!(
            e.to_string(),
            "data: MER grids differ within a batch (50x22 vs 100x44): frames of one size are \
             needed"
        );
        let e = NetError::OtherMerMaps {
            record: PathBuf::from("p/mer.json"),
            there: "a.safetensors".into(),
            there_fnv64: "1f".into(),
            requested: PathBuf::from("b.safetensors"),
        };
        assert_eq!(
            e.to_string(),
            "configuration: p/mer.json: MER maps of another PDA model (a.safetensors, fnv64 \
             1f) are there; pass --force to replace them with b.safetensors"
        );
        assert_eq!(
            NetError::RadarDropNotAFraction(1.5).to_string(),
            "configuration: --radar-drop must be within [0, 1], got 1.5"
        );
        let e = NetError::from(depthsense_config::refusal::ExplainRefusal::NoSuchLayers(
            vec!["rgb.layer9".into()],
        ));
        assert_eq!(
            e.to_string(),
            "configuration: none of the layers [\"rgb.layer9\"] exists in this network \
             (rgb.layer1..4, decoder, radar)"
        );
    }
}
