//! What a training run refuses before it trains (`train` and `mer train`), in the terms of its
//! option groups ([`crate::training`]): the groups checked on their own
//! ([`ScheduleOptions::check`], [`LoadingOptions::check`], [`MerScheduleOptions::check`]), against the data and the ranks, and a
//! continued run (`--resume`, `--extend`) against the checkpoint it continues ([`ScheduleKey`]).
//! Each variant carries the values at fault; the message says the flag and the next step.
//! `explain`'s refusals of a network it cannot explain are here too ([`ExplainRefusal`]).

use std::path::PathBuf;

use serde_json::Value;

use crate::mer_training::MerScheduleOptions;
use crate::training::{LoadingOptions, ScheduleOptions};
use crate::ModelConfig;

/// The schedule values that an exact resume keeps: a checkpoint's and the options' must be
/// equal (`--extend` changes epochs and lr first).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ScheduleKey {
    pub batch_size: usize,
    pub epochs: usize,
    pub lr: f64,
    pub seed: u64,
}

impl ScheduleKey {
    /// At least one epoch of batches of at least one sample, the global batch split evenly
    /// over `ranks` data-parallel ranks.
    fn check(&self, ranks: usize) -> Result<(), TrainingRefusal> {
        if self.batch_size == 0 || self.epochs == 0 {
            return Err(TrainingRefusal::EmptySchedule);
        }
        if !self.batch_size.is_multiple_of(ranks.max(1)) {
            return Err(TrainingRefusal::BatchNotAMultiple {
                batch: self.batch_size,
                ranks,
            });
        }
        Ok(())
    }
}

impl std::fmt::Display for ScheduleKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "batch {} epochs {} lr {} seed {}",
            self.batch_size, self.epochs, self.lr, self.seed
        )
    }
}

/// The leaves in which two JSON values differ, in key order: (the dotted path below `prefix`,
/// the stored value, the requested one), each value as a word — a string bare, `absent` for a
/// key one side lacks. Objects on both sides are compared key by key; `same` compares the rest
/// (exactly, or within a tolerance). Shared by the refusals here and the experiments' runner.
pub fn differing_leaves(
    prefix: &str,
    stored: Option<&Value>,
    requested: Option<&Value>,
    same: &dyn Fn(&Value, &Value) -> bool,
) -> Vec<(String, String, String)> {
    if let (Some(Value::Object(a)), Some(Value::Object(b))) = (stored, requested) {
        let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
        keys.sort();
        keys.dedup();
        return keys
            .into_iter()
            .flat_map(|k| {
                let path = match prefix {
                    "" => k.clone(),
                    p => format!("{p}.{k}"),
                };
                differing_leaves(&path, a.get(k), b.get(k), same)
            })
            .collect();
    }
    if let (Some(x), Some(y)) = (stored, requested) {
        if same(x, y) {
            return vec![];
        }
    }
    let word = |v: Option<&Value>| match v {
        Some(Value::String(s)) => s.clone(),
        Some(v) => v.to_string(),
        None => "absent".into(),
    };
    vec![(prefix.to_string(), word(stored), word(requested))]
}

/// One field in which two model configs differ: a checkpoint's and the one requested.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigDifference {
    /// The `--set` key of the field (the JSON field name when no key sets it).
    pub key: String,
    pub stored: String,
    pub requested: String,
}

impl ConfigDifference {
    /// The fields in which `stored` (a checkpoint's) and `requested` differ, in alphabetical
    /// order of the fields (a nested one dotted: `sid.alpha`), the name aside.
    pub fn between(stored: &ModelConfig, requested: &ModelConfig) -> Vec<ConfigDifference> {
        Self::fields(stored, requested, |f| {
            crate::options::find(f).map_or_else(|| f.to_string(), |o| o.key.to_string())
        })
    }

    /// The fields in which `stored` and `requested` differ (a PDA config, a schedule), named
    /// by their JSON field.
    pub fn between_any<T: serde::Serialize>(stored: &T, requested: &T) -> Vec<ConfigDifference> {
        Self::fields(stored, requested, str::to_string)
    }

    fn fields<T: serde::Serialize>(
        stored: &T,
        requested: &T,
        key: impl Fn(&str) -> String,
    ) -> Vec<ConfigDifference> {
        let (Ok(a), Ok(b)) = (
            serde_json::to_value(stored),
            serde_json::to_value(requested),
        ) else {
            return vec![];
        };
        differing_leaves("", Some(&a), Some(&b), &|x, y| x == y)
            .into_iter()
            .filter(|(path, ..)| path != "name")
            .map(|(path, stored, requested)| ConfigDifference {
                key: key(&path),
                stored,
                requested,
            })
            .collect()
    }

    /// The next step: the network's output size comes from the prepared data's frames (the
    /// `out-height`/`out-width` the trainer sets), every other field from `--config`/`--set`.
    fn advice(differences: &[ConfigDifference]) -> String {
        let frame = |d: &ConfigDifference| matches!(d.key.as_str(), "out-height" | "out-width");
        let (by_frame, by_flags) = (
            differences.iter().any(frame),
            differences.iter().any(|d| !frame(d)),
        );
        let mut steps = vec![];
        if by_flags || !by_frame {
            steps.push("resume with the same --config and --set");
        }
        if by_frame {
            steps.push(
                "resume on data prepared at the checkpoint's frame size (the network's output \
                 size is the prepared frames')",
            );
        }
        steps.join("; ")
    }

    /// `key: X in the checkpoint, Y requested`, joined (or why none is listed).
    fn list(differences: &[ConfigDifference]) -> String {
        if differences.is_empty() {
            return "no field differs but the name".into();
        }
        differences
            .iter()
            .map(|d| {
                format!(
                    "{}: {} in the checkpoint, {} requested",
                    d.key, d.stored, d.requested
                )
            })
            .collect::<Vec<_>>()
            .join("; ")
    }
}

/// Why a training run is refused. Read as `configuration: …` through the training stack's
/// error.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrainingRefusal {
    /// `--batch-size 0` or `--epochs 0` (the command line's ranges refuse them first; a
    /// library caller may not).
    #[error("batch size and epochs must be at least 1")]
    EmptySchedule,
    #[error("train radar drop {drop} is not a fraction in [0, 1]")]
    RadarDropNotAFraction { drop: f64 },
    /// Data-parallel training: the global batch is split evenly over the ranks.
    #[error("the global batch size {batch} is not a multiple of the {ranks} ranks")]
    BatchNotAMultiple { batch: usize, ranks: usize },
    #[error("--train-subset {requested}: {} holds only {available} training samples", .data.display())]
    SubsetTooLarge {
        requested: usize,
        data: PathBuf,
        available: usize,
    },
    #[error("{samples} training samples: fewer than one global batch of {batch}")]
    FewerSamplesThanBatch { samples: usize, batch: usize },
    #[error(
        "--extend: {} holds no run to extend (no {checkpoint}); train it first, without --extend",
        .run.display()
    )]
    NothingToExtend {
        run: PathBuf,
        checkpoint: &'static str,
    },
    #[error(
        "--resume: {} holds a different model config than requested (checkpoint preset \
         {stored:?}, requested {requested:?}; {}); {}",
        .checkpoint.display(),
        ConfigDifference::list(.differences),
        ConfigDifference::advice(.differences)
    )]
    OtherModel {
        checkpoint: PathBuf,
        stored: String,
        requested: String,
        /// Each field that differs, named by its `--set` key where it has one.
        differences: Vec<ConfigDifference>,
    },
    #[error(
        "--resume: {} was trained with {stored}; an exact resume needs the same values (got \
         {requested})",
        .checkpoint.display()
    )]
    OtherSchedule {
        checkpoint: PathBuf,
        stored: ScheduleKey,
        requested: ScheduleKey,
    },
    #[error(
        "--extend: {} has {epochs} epochs; give more with --epochs (e.g. --epochs {})",
        .checkpoint.display(),
        .epochs * 2
    )]
    ExtendWithoutMoreEpochs { checkpoint: PathBuf, epochs: usize },
    #[error(
        "--extend: {} was trained with batch {} seed {}; an extension keeps them (got batch {} \
         seed {})",
        .checkpoint.display(), .stored.batch_size, .stored.seed, .requested.batch_size,
        .requested.seed
    )]
    ExtendChangesBatchOrSeed {
        checkpoint: PathBuf,
        stored: ScheduleKey,
        requested: ScheduleKey,
    },
    /// `mer train --resume`: the PDA network's config or the schedule differ.
    #[error(
        "--resume: {} was trained with another PDA config or batch/epochs/lr/seed ({}); an \
         exact resume needs the same options",
        .checkpoint.display(),
        ConfigDifference::list(.differences)
    )]
    OtherPdaRun {
        checkpoint: PathBuf,
        differences: Vec<ConfigDifference>,
    },
}

impl ScheduleOptions {
    /// The values an exact resume keeps.
    pub fn key(&self) -> ScheduleKey {
        ScheduleKey {
            batch_size: self.batch_size,
            epochs: self.epochs,
            lr: self.lr,
            seed: self.seed,
        }
    }

    /// At least one epoch of batches of at least one sample, the global batch split evenly
    /// over `ranks` data-parallel ranks (1: a single process).
    pub fn check(&self, ranks: usize) -> Result<(), TrainingRefusal> {
        self.key().check(ranks)
    }
}

impl MerScheduleOptions {
    /// The values an exact resume keeps.
    pub fn key(&self) -> ScheduleKey {
        ScheduleKey {
            batch_size: self.batch_size,
            epochs: self.epochs,
            lr: self.lr,
            seed: self.seed,
        }
    }

    /// At least one epoch of batches of at least one sample (`mer train` runs one process).
    pub fn check(&self) -> Result<(), TrainingRefusal> {
        self.key().check(1)
    }
}

impl LoadingOptions {
    /// `--train-radar-drop` a fraction.
    pub fn check(&self) -> Result<(), TrainingRefusal> {
        if !(0.0..=1.0).contains(&self.train_radar_drop) {
            return Err(TrainingRefusal::RadarDropNotAFraction {
                drop: self.train_radar_drop,
            });
        }
        Ok(())
    }
}

/// What `explain` (Grad-CAM++ over the ordinal head) refuses to explain. Read as
/// `configuration: …` through the training stack's error.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ExplainRefusal {
    #[error("explain needs an ordinal head at low resolution (not l1/l2, not clamp_logits)")]
    NotOrdinal,
    #[error("none of the layers {0:?} exists in this network (rgb.layer1..4, decoder, radar)")]
    NoSuchLayers(Vec<String>),
    #[error("explain supports the raw or height radar input, not {}", .0.name())]
    RadarInput(crate::RadarInput),
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The messages the trainer's strings had, now from the typed values.
    #[test]
    fn refusals_read_as_the_strings_they_replaced() {
        let key = |batch_size, seed| ScheduleKey {
            batch_size,
            epochs: 2,
            lr: 0.001,
            seed,
        };
        let last = PathBuf::from("run/last.safetensors");
        let cases = [
            (
                TrainingRefusal::OtherSchedule {
                    checkpoint: last.clone(),
                    stored: key(8, 0),
                    requested: key(4, 0),
                },
                "--resume: run/last.safetensors was trained with batch 8 epochs 2 lr 0.001 seed 0; \
                 an exact resume needs the same values (got batch 4 epochs 2 lr 0.001 seed 0)",
            ),
            (
                TrainingRefusal::ExtendWithoutMoreEpochs {
                    checkpoint: last.clone(),
                    epochs: 3,
                },
                "--extend: run/last.safetensors has 3 epochs; give more with --epochs (e.g. \
                 --epochs 6)",
            ),
            (
                TrainingRefusal::ExtendChangesBatchOrSeed {
                    checkpoint: last.clone(),
                    stored: key(8, 0),
                    requested: key(8, 5),
                },
                "--extend: run/last.safetensors was trained with batch 8 seed 0; an extension \
                 keeps them (got batch 8 seed 5)",
            ),
            (
                TrainingRefusal::NothingToExtend {
                    run: "run".into(),
                    checkpoint: "last.safetensors",
                },
                "--extend: run holds no run to extend (no last.safetensors); train it first, \
                 without --extend",
            ),
            (
                TrainingRefusal::OtherModel {
                    checkpoint: last,
                    stored: "tiny".into(),
                    requested: "tiny".into(),
                    differences: ConfigDifference::between(&ModelConfig::tiny(), &{
                        let mut c = ModelConfig::tiny();
                        c.set_option("input-downscale", "2").unwrap();
                        c.set_option("width", "8").unwrap();
                        c
                    }),
                },
                "--resume: run/last.safetensors holds a different model config than requested \
                 (checkpoint preset \"tiny\", requested \"tiny\"; width: 16 in the checkpoint, 8 \
                 requested; input-downscale: 1 in the checkpoint, 2 requested); resume with the \
                 same --config and --set",
            ),
        ];
        let pda = TrainingRefusal::OtherPdaRun {
            checkpoint: "mer/last.safetensors".into(),
            differences: ConfigDifference::between_any(&key(8, 0), &key(8, 3)),
        };
        assert_eq!(
            pda.to_string(),
            "--resume: mer/last.safetensors was trained with another PDA config or \
             batch/epochs/lr/seed (seed: 0 in the checkpoint, 3 requested); an exact resume needs \
             the same options"
        );
        let frame = TrainingRefusal::OtherModel {
            checkpoint: "run/last.safetensors".into(),
            stored: "tiny".into(),
            requested: "tiny".into(),
            differences: ConfigDifference::between(&ModelConfig::tiny(), &{
                let mut c = ModelConfig::tiny();
                c.out_height = 176;
                c
            }),
        };
        assert!(
            frame.to_string().ends_with(&format!(
                "out-height: {} in the checkpoint, 176 requested); resume on data prepared at \
                 the checkpoint's frame size (the network's output size is the prepared \
                 frames')",
                ModelConfig::tiny().out_height
            )),
            "{frame}"
        );
        // A nested field is named by its dotted path, not shown as the whole object.
        let mut beta = ModelConfig::tiny();
        beta.sid.beta_m = 60.0;
        assert_eq!(
            ConfigDifference::between(&ModelConfig::tiny(), &beta),
            [ConfigDifference {
                key: "sid.beta_m".into(),
                stored: format!("{:?}", ModelConfig::tiny().sid.beta_m),
                requested: "60.0".into(),
            }]
        );
        for (e, says) in cases {
            assert_eq!(e.to_string(), says);
        }
    }

    #[test]
    fn the_groups_check_themselves() {
        let mut s = ScheduleOptions::default();
        assert_eq!(s.check(1), Ok(()));
        s.batch_size = 6;
        assert_eq!(
            s.check(4),
            Err(TrainingRefusal::BatchNotAMultiple { batch: 6, ranks: 4 })
        );
        assert_eq!(s.check(3), Ok(()));
        s.epochs = 0;
        assert_eq!(s.check(1), Err(TrainingRefusal::EmptySchedule));
        let mut l = LoadingOptions::default();
        assert_eq!(l.check(), Ok(()));
        l.train_radar_drop = 1.5;
        assert_eq!(
            l.check(),
            Err(TrainingRefusal::RadarDropNotAFraction { drop: 1.5 })
        );
        assert_eq!(
            l.check().unwrap_err().to_string(),
            "train radar drop 1.5 is not a fraction in [0, 1]"
        );
    }
}
