//! `RUN/config.json`: what a training run was started with — `train`'s
//! ([`TrainRunConfig`]: `"train"` options, `"model"`, `"device"`, `"partition"`, `"schedule"`
//! of an extended run, `"init_from"` of a fine-tuning, `"command"`) or `mer train`'s
//! ([`MerRunConfig`]: `"mer_train"` options, `"pda"`, `"parameters"`, …).
//!
//! Versions: 1 (no `format_version`: every run written before records were typed), 2 (the same
//! fields plus `format_version`).

use std::path::Path;

use depthsense_config::Fusion;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::{checked, legacy, read_value, RecordError, Rest, Versioned};

/// The `format_version` `train` and `mer train` write in config.json.
pub const RUN_CONFIG_VERSION: u32 = 2;

/// A training command's options as config.json records them (`"train"`, `"mer_train"`): the
/// fields the readers use, typed; every other option as written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunOptions {
    /// The prepared folder it trains on.
    pub data: String,
    /// The run folder.
    pub out: String,
    /// Epochs of the run (an `--extend`ed run: the new total).
    pub epochs: u64,
    pub batch_size: u64,
    pub lr: f64,
    pub seed: u64,
    #[serde(flatten)]
    pub rest: Rest,
}

/// The network of a `train` run (`"model"`, the whole `ModelConfig` as written): what the
/// report says of it typed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelSummary {
    /// The preset it was built from.
    pub name: String,
    pub fusion: Fusion,
    pub attention: bool,
    #[serde(flatten)]
    pub rest: Rest,
}

impl ModelSummary {
    /// "late fusion + attention", "late fusion", "early fusion", "RGB only".
    pub fn fusion_words(&self) -> &'static str {
        match (self.fusion, self.attention) {
            (Fusion::Late, true) => "late fusion + attention",
            (Fusion::Late, false) => "late fusion",
            (Fusion::Early, _) => "early fusion",
            (Fusion::None, _) => "RGB only",
        }
    }
}

/// How the prepared scenes were split (`"partition"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PartitionRecord {
    pub train_samples: u64,
    /// Validation samples each validation scores (`--max-val-samples` of the partition's).
    pub val_samples_used: u64,
    /// `method`, `val_samples`, `val_scenes`.
    #[serde(flatten)]
    pub rest: Rest,
}

/// One segment of an extended run's learning-rate schedule (`"schedule"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LrSegment {
    pub start_iteration: u64,
    pub end_iteration: u64,
    pub lr: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub warmup: u64,
}

fn is_zero(x: &u64) -> bool {
    *x == 0
}

/// What `--init-from` loaded into the fresh network (`"init_from"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InitFrom {
    pub file: String,
    /// Tensors loaded whole.
    pub loaded: u64,
    /// Tensors of the network the file lacks (left at their initialisation).
    pub new: Vec<String>,
    /// `partly_loaded`, `unused_file_tensors`.
    #[serde(flatten)]
    pub rest: Rest,
}

/// The invocation that started a run (`"command"`): its words, program first (or one line).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Command {
    Words(Vec<String>),
    Line(String),
}

impl Command {
    /// `None` for an empty argv (nothing to record).
    pub fn of_words(words: &[String]) -> Option<Self> {
        (!words.is_empty()).then(|| Self::Words(words.to_vec()))
    }

    /// One shell line (words quoted where a shell would need it); `None` when empty.
    pub fn shell_line(&self) -> Option<String> {
        match self {
            Self::Words(words) => (!words.is_empty()).then(|| {
                words
                    .iter()
                    .map(|w| shell_word(w))
                    .collect::<Vec<_>>()
                    .join(" ")
            }),
            Self::Line(line) => Some(line.clone()),
        }
    }
}

/// `w` as a shell reads it back: unchanged when plain, else in single quotes.
fn shell_word(w: &str) -> String {
    let plain = !w.is_empty()
        && w.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=:,+@%".contains(c));
    if plain {
        w.to_string()
    } else {
        format!("'{}'", w.replace('\'', "'\\''"))
    }
}

/// `train`'s config.json.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainRunConfig {
    #[serde(default = "legacy")]
    pub format_version: u32,
    pub train: RunOptions,
    pub model: ModelSummary,
    /// The device in words (absent from no run `train` wrote; optional for hand-made folders).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device: Option<String>,
    pub partition: PartitionRecord,
    /// An extended run's learning-rate segments (absent: never extended).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub schedule: Vec<LrSegment>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init_from: Option<InitFrom>,
    /// Absent: a run written before the command was recorded, or one an experiment made.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command: Option<Command>,
}

impl Versioned for TrainRunConfig {
    const CURRENT: u32 = RUN_CONFIG_VERSION;
    fn format_version(&self) -> u32 {
        self.format_version
    }
}

/// `mer train`'s config.json.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MerRunConfig {
    #[serde(default = "legacy")]
    pub format_version: u32,
    pub mer_train: RunOptions,
    /// The PDA network's config as written (`config::pda::PdaConfig`; no reader uses it: the
    /// checkpoint holds the one a network is built from).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pda: Option<Value>,
    /// Trainable parameters of the PDA network.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parameters: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub partition: Option<PartitionRecord>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command: Option<Command>,
}

impl Versioned for MerRunConfig {
    const CURRENT: u32 = RUN_CONFIG_VERSION;
    fn format_version(&self) -> u32 {
        self.format_version
    }
}

/// A run's config.json: `train`'s or `mer train`'s (the one with `"mer_train"`).
#[derive(Debug, Clone, PartialEq)]
pub enum RunConfig {
    Train(Box<TrainRunConfig>),
    Mer(Box<MerRunConfig>),
}

impl RunConfig {
    /// Read `path`: an error names the file and the field.
    pub fn read(path: &Path) -> Result<Self, RecordError> {
        Self::from_value(read_value(path)?, path)
    }

    /// A config.json's JSON (`path`: named in errors).
    pub fn from_value(v: Value, path: &Path) -> Result<Self, RecordError> {
        if v.get("mer_train").is_some() {
            Ok(Self::Mer(Box::new(checked(v, path, None)?)))
        } else {
            Ok(Self::Train(Box::new(checked(v, path, None)?)))
        }
    }

    /// The training command's options (`train` or `mer_train`).
    pub fn options(&self) -> &RunOptions {
        match self {
            Self::Train(c) => &c.train,
            Self::Mer(c) => &c.mer_train,
        }
    }

    pub fn command(&self) -> Option<&Command> {
        match self {
            Self::Train(c) => c.command.as_ref(),
            Self::Mer(c) => c.command.as_ref(),
        }
    }

    pub fn format_version(&self) -> u32 {
        match self {
            Self::Train(c) => c.format_version,
            Self::Mer(c) => c.format_version,
        }
    }
}
