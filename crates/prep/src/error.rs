//! Errors of `prepare`, `index` and `inspect`: each names the file, split or setting at fault.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use depthsense_nuscenes::NuError;

/// An error of the prepare pipeline.
#[derive(Debug, thiserror::Error)]
pub enum PrepError {
    #[error(transparent)]
    Nu(#[from] depthsense_nuscenes::NuError),
    #[error("unknown split {0:?}; expected one of train, val, test, test-day, test-night, test-rain, official-train, official-val, all")]
    UnknownSplit(String),
    #[error("split {split:?} matches no scene of {version} ({scenes} scenes); synthetic or partial datasets have their own scene tokens: use --split all")]
    EmptySplit {
        split: String,
        version: String,
        scenes: usize,
    },
    /// A write of the output folder's shared files (index, locks, a moved sample) that failed.
    #[error("{}: {source}", .path.display())]
    Output {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// `index merge`: a folder to merge that holds no index.
    #[error("{}: holds no index.json or index.shard-*.json", .dir.display())]
    NoIndexToMerge { dir: PathBuf },
    /// `index merge OUT` with neither shard indexes in OUT nor other folders.
    #[error(
        "{}: nothing to merge: no index.shard-*.json here and no other folder given (`index \
         merge OUT` combines the index.shard-I-of-N.json files that `prepare --shard I/N --out \
         OUT` wrote; `index merge OUT OTHER…` adds the samples of other prepared folders)",
        .out.display()
    )]
    NothingToMerge { out: PathBuf },
    /// `index merge`: a sample folder that `index` lists but that is not complete.
    #[error(
        "{}: listed in {} but not complete (no meta.json)",
        .sample.display(),
        .index.display()
    )]
    IncompleteSource { sample: PathBuf, index: PathBuf },
    /// `index merge`: a sample folder that cannot be moved into the output folder.
    #[error(
        "{}: cannot move to {} ({source}); shard folders must be on the output's filesystem",
        .from.display(),
        .to.display()
    )]
    CannotMove {
        from: PathBuf,
        to: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A prepared sample's meta.json that cannot be parsed (checked against this run's settings).
    #[error("{}: unreadable meta.json: {source}", .path.display())]
    UnreadableMeta {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    /// A split list (`--splits`) that exists but cannot be read.
    #[error("{}: cannot read split list: {source}", .path.display())]
    SplitList {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Lock(#[from] depthsense_base::lock::LockError),
    /// A prepared folder (or sample folder, `path`) made with other map settings: `what` is
    /// the first setting that differs, `old` its value there, `new` this run's.
    #[error("{} was prepared with different settings ({what}: {old} there, {new} now); use another --out or remove it", .path.display())]
    SettingsMismatch {
        path: PathBuf,
        what: String,
        old: String,
        new: String,
    },
    /// An index file (`path`) that exists but is not a prepared index.
    #[error(
        "{}: unreadable prepared index ({source}); it is not replaced: repair or remove it",
        .path.display()
    )]
    CorruptIndex {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    /// A prepared index (`path`) of another dataset version than this run's.
    #[error("{} holds dataset version {old:?}, this run is {new:?}; use another --out", .path.display())]
    VersionMismatch {
        path: PathBuf,
        old: String,
        new: String,
    },
    /// Two indexes given to `index merge` that were not prepared alike: `what` (the dataset
    /// version or a map setting) is `old` in `against`, `new` in `path`.
    #[error(
        "{}: {what} is {new}, but {old} in {}; index merge takes indexes prepared with the same \
         version and settings only",
        .path.display(),
        .against.display()
    )]
    IndexesDisagree {
        path: PathBuf,
        against: PathBuf,
        what: String,
        old: String,
        new: String,
    },
    #[error("sample {sample} panicked while reading {input}: {reason}")]
    Panicked {
        sample: String,
        input: String,
        reason: String,
    },

    // --- Sharded `prepare` (`--shard I/N`) and the merge of its shard indexes ---
    /// A `--shard` value (`value`, as written) that is not I/N with 0 ≤ I < N; `fault` says
    /// why.
    #[error("--shard {value:?}: {}; expected I/N with 0 ≤ I < N", .fault.text())]
    BadShard { value: String, fault: ShardFault },
    /// Shard indexes of different shard counts (`counts`: the Ns) among the sources of a
    /// merge into `out`.
    #[error(
        "shard indexes of different N ({counts:?}) in {}; merge one sharding at a time",
        .out.display()
    )]
    MixedShardCounts {
        out: PathBuf,
        counts: BTreeSet<usize>,
    },
    /// Shard `index` of `count` found in more than one source of a merge.
    #[error("shard {index}/{count} appears twice among the sources")]
    DuplicateShard { index: usize, count: usize },
    /// Shards (`missing`, by number) of `count` whose index no source of a merge holds.
    #[error(
        "shards {missing:?} of {count} are missing (no {} for them); run them first",
        missing_shard_files(.missing, *.count)
    )]
    MissingShards { missing: Vec<usize>, count: usize },

    /// A file that cannot be encoded before it is written (a sample's PNG or `meta.json`, an
    /// index, a calibration JSON, a bench table); `path` names it.
    #[error("{path}: cannot encode: {source}")]
    Encode {
        path: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A 16-bit depth PNG that cannot be read (`inspect`).
    #[error(transparent)]
    DepthPng(#[from] depthsense_nuscenes::depth_png::DepthPngError),
    /// A `radar_points.bin` that cannot be read (`inspect`).
    #[error(transparent)]
    RadarPoints(#[from] crate::radar_points::RadarPointsError),
    /// The worker threads of `prepare --jobs` cannot be started.
    #[error("thread pool: {0}")]
    ThreadPool(#[source] rayon::ThreadPoolBuildError),
    /// The validation split is drawn from a version's scene table, not from a shipped list.
    #[error("split \"val\" is chosen per scene table: use splits::assign_splits")]
    ValPerSceneTable,
    /// `bench prepare` asked for a world of no keyframes.
    #[error("the bench world needs at least one keyframe")]
    BenchNoKeyframes,
    /// The bench's fixture folder is not the nuscenes-kf0 fixture: `missing` says what it
    /// lacks (a channel's keyframe, the camera's intrinsic).
    #[error("{path}: not the nuscenes-kf0 fixture (no {missing})")]
    NotKf0Fixture { path: String, missing: &'static str },
    /// A sample of the bench's world failed to prepare.
    #[error("bench prepare failed on {sample}: {reason}")]
    BenchPrepareFailed { sample: String, reason: String },
}

/// Why a `--shard` value is not I/N with 0 ≤ I < N.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShardFault {
    /// No `/` between I and N.
    NoSlash,
    /// I is not a number.
    IndexNotANumber,
    /// N is not a number.
    CountNotANumber,
    /// N is 0, or I is not below N.
    OutOfRange,
}

impl ShardFault {
    /// The words of the message.
    pub fn text(self) -> &'static str {
        match self {
            Self::NoSlash => "no '/'",
            Self::IndexNotANumber => "I is not a number",
            Self::CountNotANumber => "N is not a number",
            Self::OutOfRange => "out of range",
        }
    }
}

/// The shard index files of the `missing` shards of `count`, comma-separated.
fn missing_shard_files(missing: &[usize], count: usize) -> String {
    missing
        .iter()
        .map(|i| crate::layout::shard_index_file(*i, count))
        .collect::<Vec<_>>()
        .join(", ")
}

impl PrepError {
    /// A failed read or write of `path` (the reader's error, naming the file).
    pub(crate) fn io(path: &Path, e: std::io::Error) -> Self {
        PrepError::Nu(NuError::io(path, e))
    }

    /// A file's bytes cannot be encoded; `path` names the file.
    pub(crate) fn encode(
        path: impl std::fmt::Display,
        source: impl std::error::Error + Send + Sync + 'static,
    ) -> Self {
        PrepError::Encode {
            path: path.to_string(),
            source: Box::new(source),
        }
    }

    /// A failed write of the output folder's shared files (index, locks).
    pub(crate) fn output(path: &Path, e: std::io::Error) -> Self {
        PrepError::Output {
            path: path.to_path_buf(),
            source: e,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each typed variant names the file, split or fixture at fault, with the words the
    /// strings it replaced used.
    #[test]
    fn typed_variants_name_what_went_wrong() {
        let png = depthsense_nuscenes::depth_png::DepthPngError::Size {
            width: 2,
            height: 1,
            got: 1,
            want: 2,
        };
        assert_eq!(
            PrepError::encode("tok/lidar_sparse.png", png).to_string(),
            "tok/lidar_sparse.png: cannot encode: depth map has 1 values but 2x1 needs 2"
        );
        assert_eq!(
            crate::split_scene_tokens("val").unwrap_err().to_string(),
            "split \"val\" is chosen per scene table: use splits::assign_splits"
        );
        assert_eq!(
            PrepError::BenchNoKeyframes.to_string(),
            "the bench world needs at least one keyframe"
        );
        let e = PrepError::NotKf0Fixture {
            path: "fx".into(),
            missing: "LIDAR_TOP keyframe",
        };
        assert_eq!(
            e.to_string(),
            "fx: not the nuscenes-kf0 fixture (no LIDAR_TOP keyframe)"
        );
        let e = PrepError::BenchPrepareFailed {
            sample: "s1".into(),
            reason: "no lidar".into(),
        };
        assert_eq!(e.to_string(), "bench prepare failed on s1: no lidar");
    }

    /// A `--shard` value that is not I/N says why, with the words it always had.
    #[test]
    fn a_bad_shard_value_says_why() {
        let cases = [
            ("1", ShardFault::NoSlash, "no '/'"),
            ("a/3", ShardFault::IndexNotANumber, "I is not a number"),
            ("1/b", ShardFault::CountNotANumber, "N is not a number"),
            ("16/16", ShardFault::OutOfRange, "out of range"),
            ("0/0", ShardFault::OutOfRange, "out of range"),
        ];
        for (value, want, why) in cases {
            let e = value.parse::<crate::Shard>().unwrap_err();
            assert!(
                matches!(&e, PrepError::BadShard { value: v, fault } if v == value && *fault == want),
                "{value}: {e:?}"
            );
            assert_eq!(
                e.to_string(),
                format!("--shard {value:?}: {why}; expected I/N with 0 ≤ I < N")
            );
        }
    }

    /// A merge's refused shard sets name the shards, counts and files at fault.
    #[test]
    fn shard_set_refusals_read_as_before() {
        let e = PrepError::MixedShardCounts {
            out: "prepared".into(),
            counts: [2, 3].into(),
        };
        assert_eq!(
            e.to_string(),
            "shard indexes of different N ({2, 3}) in prepared; merge one sharding at a time"
        );
        let e = PrepError::DuplicateShard { index: 1, count: 3 };
        assert_eq!(e.to_string(), "shard 1/3 appears twice among the sources");
        let e = PrepError::MissingShards {
            missing: vec![0, 2],
            count: 3,
        };
        assert_eq!(
            e.to_string(),
            "shards [0, 2] of 3 are missing (no index.shard-0-of-3.json, \
             index.shard-2-of-3.json for them); run them first"
        );
    }

    /// A bad depth PNG given to `inspect` is the reader's own error, its cause kept.
    #[test]
    fn inspect_keeps_the_readers_error() {
        let e: PrepError = depthsense_nuscenes::depth_png::DepthPngError::Format {
            path: "a.png".into(),
            found: "Rgb8".into(),
        }
        .into();
        assert_eq!(
            e.to_string(),
            "a.png: expected a 16-bit single-channel PNG, found Rgb8"
        );
    }

    /// The output folder's failures read as the strings they replaced, the io error kept as the
    /// source.
    #[test]
    fn output_failures_keep_their_cause() {
        use std::error::Error;
        let io = || std::io::Error::from(std::io::ErrorKind::PermissionDenied);
        let e = PrepError::output(Path::new("out/index.json"), io());
        assert_eq!(e.to_string(), format!("out/index.json: {}", io()));
        assert!(e.source().is_some());
        let e = PrepError::CannotMove {
            from: "a/s1".into(),
            to: "out/s1".into(),
            source: io(),
        };
        assert_eq!(
            e.to_string(),
            format!(
                "a/s1: cannot move to out/s1 ({}); shard folders must be on the output's \
                 filesystem",
                io()
            )
        );
        let e = PrepError::IncompleteSource {
            sample: "a/s1".into(),
            index: "a/index.json".into(),
        };
        assert_eq!(
            e.to_string(),
            "a/s1: listed in a/index.json but not complete (no meta.json)"
        );
        let e = PrepError::NoIndexToMerge { dir: "b".into() };
        assert_eq!(
            e.to_string(),
            "b: holds no index.json or index.shard-*.json"
        );
    }
}
