//! Errors of the train crate: each names the file, record or setting at fault.

use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: cannot parse: {reason}")]
    Parse { path: String, reason: String },
    #[error("data: {0}")]
    Data(String),
    #[error("configuration: {0}")]
    Config(String),
    #[error(transparent)]
    Model(#[from] depthsense_model::ModelError),
    #[error(transparent)]
    Metrics(#[from] depthsense_metrics::MetricsError),
    #[error(transparent)]
    Viz(#[from] depthsense_viz::VizError),
    #[error("libtorch: {0}")]
    Torch(#[from] tch::TchError),
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
    #[error("{dir} already holds {what}; nothing was changed: {advice}")]
    OutputExists {
        dir: String,
        what: String,
        advice: String,
    },
    #[error(transparent)]
    Lock(#[from] depthsense_base::lock::LockError),
    /// Prepared samples that cannot be read, every one with its reason (the loader reads on
    /// past them, so that `eval` and `predict` name them all at once), and how to rebuild them.
    #[error("{}", unreadable_text(.root, .samples))]
    Unreadable {
        /// The prepared folder.
        root: String,
        /// (sample token, what is wrong), in the order they were met.
        samples: Vec<(String, String)>,
    },
    /// `train --resume` of a run that has run all its epochs: nothing to do (exit status 0).
    #[error(
        "{run} is finished: {epochs} of {epochs} epochs (iteration {iteration}); nothing was \
         changed. To train it longer, run the same command with --extend --epochs N (N > \
         {epochs}): a new learning-rate schedule from its last checkpoint \
         (docs/guide/train.md, \"Longer runs and fine-tuning\")"
    )]
    RunFinished {
        run: String,
        epochs: usize,
        iteration: u64,
    },
    /// The torch-free data layer's errors that have no variant of their own here.
    #[error(transparent)]
    Dataset(depthsense_dataset::DataError),
    #[error("{0}")]
    Other(String),
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

impl TrainError {
    /// One error for several: every [`TrainError::Unreadable`] merged into one, unless another
    /// kind is among them (then the first of those). `None` for none.
    pub fn merged(errors: Vec<TrainError>) -> Option<TrainError> {
        let mut root = None;
        let mut samples = vec![];
        for e in errors {
            match e {
                TrainError::Unreadable {
                    root: r,
                    samples: s,
                } => {
                    root.get_or_insert(r);
                    samples.extend(s);
                }
                other => return Some(other),
            }
        }
        root.map(|root| TrainError::Unreadable { root, samples })
    }

    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.display().to_string(),
            source,
        }
    }
}

impl From<depthsense_dist::DistError> for TrainError {
    fn from(e: depthsense_dist::DistError) -> Self {
        TrainError::Other(e.to_string())
    }
}

/// An unknown preset or `--set` key, or a config no network can be built with.
impl From<depthsense_model::config::ConfigError> for TrainError {
    fn from(e: depthsense_model::config::ConfigError) -> Self {
        use depthsense_model::config::ConfigError as C;
        match e {
            // a mismatch between a request and the model, not an invalid model (same message
            // as when the trainer owned the rule)
            C::RadarChannels { .. } => TrainError::Config(e.to_string()),
            e => TrainError::Model(e.into()),
        }
    }
}

/// The torch-free layer's errors become the same variants here (same messages).
impl From<depthsense_dataset::DataError> for TrainError {
    fn from(e: depthsense_dataset::DataError) -> Self {
        use depthsense_dataset::DataError as D;
        match e {
            D::Io { path, source } => TrainError::Io { path, source },
            D::Parse { path, reason } => TrainError::Parse { path, reason },
            D::Data(m) => TrainError::Data(m),
            D::Config(m) => TrainError::Config(m),
            D::Metrics(m) => TrainError::Metrics(m),
            D::OutputExists { dir, what, advice } => TrainError::OutputExists { dir, what, advice },
            D::Other(m) => TrainError::Other(m),
            other => TrainError::Dataset(other),
        }
    }
}
