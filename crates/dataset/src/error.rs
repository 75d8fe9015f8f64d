//! The error of the torch-free data layer: each names the file, record or setting at fault.
//! `depthsense_infer::NetError` carries it whole (`NetError::Dataset`), messages unchanged.

use std::path::{Path, PathBuf};

use depthsense_prep::layout::META_FILE;

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
    #[error("data: {0}")]
    Data(String),
    #[error("configuration: {0}")]
    Config(String),
    #[error(transparent)]
    Metrics(#[from] depthsense_metrics::MetricsError),
    #[error("{dir} already holds {what}; nothing was changed: {advice}")]
    OutputExists {
        dir: String,
        what: String,
        advice: String,
    },
    /// `--data` is not a prepared folder (no `index.json`); what it is instead says what to do.
    #[error("{}", no_index_text(.root, .found))]
    NoIndex { root: String, found: NotPrepared },
    /// `--sample` (or the Python module's `read_sample`) is not one prepared sample's folder
    /// (no `meta.json`); what it is instead says what to pass.
    #[error("{}", not_a_sample_text(.dir, .found))]
    NotASample { dir: String, found: SampleFolder },
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
