//! The experiments' error, in their own terms: what an experiment's description refuses
//! before anything runs ([`SpecRefusal`]), what its data or its run folders lack, the demo's
//! stages, and — whole, with its own message — what a run, an evaluation or a file below the
//! experiments reported ([`NetError`]).

use std::path::PathBuf;

use depthsense_infer::NetError;

#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    /// A training run, an evaluation or a file below the experiment.
    #[error(transparent)]
    Net(#[from] NetError),
    /// The experiment's own description, refused before anything runs.
    #[error("configuration: {0}")]
    Spec(#[from] SpecRefusal),
    /// A run folder that an earlier invocation made with other options than this one asks
    /// for; `differences` names each differing key (`lr: 0.002 there, 0.01 asked`).
    #[error(
        "configuration: {}: this run was made with other training options (see its {file}) \
         than this experiment asks for ({}); use another --out, or delete the run to redo it",
        .run.display(),
        differences_text(.differences)
    )]
    OtherRun {
        run: PathBuf,
        file: &'static str,
        differences: Vec<String>,
    },
    /// The prepared data holds no test samples, and `experiment` reports on them.
    #[error(
        "data: {}: no test samples ({method}): {experiment} reports on the test scenes, never \
         on the validation scenes its checkpoints are selected on; prepare the data with a \
         test split (or without split lists, so that scenes are held out for test)",
        .data.display()
    )]
    NoTestSamples {
        data: PathBuf,
        method: String,
        experiment: &'static str,
    },
    /// A finished run without its best checkpoint: no epoch improved the validation RMSE.
    #[error(
        "data: {}: missing — no epoch improved the validation RMSE (non-finite?)",
        .0.display()
    )]
    NoBestCheckpoint(PathBuf),
    /// An experiment's training run ended before its last iteration (interrupted or stopped).
    #[error("{}: training stopped at iteration {done} of {total}", .run.display())]
    TrainingStopped { run: PathBuf, done: u64, total: u64 },
    /// One stage of the demo's pipeline (`synth`, `prepare`, `report`), its own error kept
    /// whole.
    #[error("{stage}: {source}")]
    Stage {
        stage: &'static str,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The demo's prepare step could not prepare every sample of its world.
    #[error("data: prepare failed for {count} sample(s), first: {first} ({reason})")]
    PrepareFailed {
        count: usize,
        first: String,
        reason: String,
    },
    /// A sample token the prepared index does not hold.
    #[error("data: sample {0} not in the index")]
    SampleNotInIndex(String),
    /// The output folder holds an earlier result, kept.
    #[error("{} already holds {what}; nothing was changed: {advice}", .dir.display())]
    OutputExists {
        dir: PathBuf,
        what: String,
        advice: String,
    },
}

fn differences_text(differences: &[String]) -> String {
    match differences.is_empty() {
        true => "no key differs".to_string(),
        false => differences.join("; "),
    }
}

/// What an experiment's description (its variants, seeds, arms, sizes, scenarios,
/// perturbations, grid) refuses, with the values at fault.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SpecRefusal {
    /// An empty list (`what`: "ablation variants", "seeds", "arms", …).
    #[error("no {0} given")]
    NothingGiven(&'static str),
    /// One item of a list given twice (`what`: "variant", "seed", "arm", "grid cell").
    #[error("{what} {item} given twice")]
    GivenTwice { what: &'static str, item: String },
    #[error(
        "arm {arm:?}: the oracle radar needs a variant that reads the radar maps (early, late, \
         late-sam, l1, l2), e.g. late-sam+oracle"
    )]
    OracleWithoutRadar { arm: String },
    #[error(
        "arm {arm:?}: {setting:?} is not a model option the arm may set (key=value; fusion, \
         attention and head are the variant's)"
    )]
    ArmSetting { arm: String, setting: String },
    /// A `--set` of a key that the ablation's variants set themselves.
    #[error("--set {setting}: {key} is what the ablation variants set; choose variants instead")]
    SetsVariantKey { setting: String, key: String },
    #[error("a training-set size of 0")]
    ZeroSize,
    #[error(
        "data-scale sets the iterations per epoch itself (the largest size's pass split over \
         --epochs); drop --epoch-iterations and use --iterations for the total"
    )]
    EpochIterationsGiven,
    #[error(
        "size {size}: {} holds only {available} training samples; generate a larger world \
         (`depthsense synth --scenes … --lean`, docs/guide/experiments.md) or pass smaller \
         --sizes",
        .data.display()
    )]
    SizeExceedsData {
        size: usize,
        data: PathBuf,
        available: usize,
    },
    #[error(
        "--iterations {iterations} × batch {batch} < {largest}: the largest training set would \
         not be seen once; pass at least {needed} iterations"
    )]
    TooFewIterations {
        iterations: u64,
        batch: usize,
        largest: usize,
        needed: usize,
    },
    #[error("perturbation magnitudes must be non-negative numbers, got {0}")]
    NegativeMagnitude(f64),
    #[error(
        "failure scenario {scenario:?}: cannot read {setting:?} (radar-drop=F, \
         drop-radars=A+B, beyond=M, clutter=N, none)"
    )]
    UnreadableScenario { scenario: String, setting: String },
    #[error("{scenario}: radar-drop must be within [0, 1]")]
    RadarDropOutOfRange { scenario: String },
}

/// The errors of the layers below that reach the experiments through `?`, each as the
/// [`NetError`] the training stack makes of it.
macro_rules! through_net_error {
    ($($t:ty),* $(,)?) => {$(
        impl From<$t> for ExperimentError {
            fn from(e: $t) -> Self {
                ExperimentError::Net(e.into())
            }
        }
    )*};
}

through_net_error!(
    depthsense_config::ConfigError,
    depthsense_model::ModelError,
    depthsense_dataset::DataError,
    depthsense_metrics::MetricsError,
    depthsense_viz::VizError,
    tch::TchError,
    depthsense_base::lock::LockError,
    serde_json::Error,
);

#[cfg(test)]
mod tests {
    use super::*;

    /// Each refusal reads as the string it replaced (or, where one string covered several
    /// lists, names the list).
    #[test]
    fn refusals_read_with_their_values() {
        let e = ExperimentError::from(SpecRefusal::GivenTwice {
            what: "seed",
            item: "3".into(),
        });
        assert_eq!(e.to_string(), "configuration: seed 3 given twice");
        let e = ExperimentError::from(SpecRefusal::NothingGiven("ablation variants"));
        assert_eq!(e.to_string(), "configuration: no ablation variants given");
        let e = ExperimentError::OtherRun {
            run: PathBuf::from("out/runs/rgb/seed0"),
            file: "run.json",
            differences: vec!["lr: 0.002 there, 0.01 asked".into()],
        };
        assert_eq!(
            e.to_string(),
            "configuration: out/runs/rgb/seed0: this run was made with other training options \
             (see its run.json) than this experiment asks for (lr: 0.002 there, 0.01 asked); \
             use another --out, or delete the run to redo it"
        );
        let e = ExperimentError::TrainingStopped {
            run: PathBuf::from("runs/a/rgb"),
            done: 3,
            total: 10,
        };
        assert_eq!(
            e.to_string(),
            "runs/a/rgb: training stopped at iteration 3 of 10"
        );
    }

    /// A stage's error is its cause, kept whole: the message holds it once, and the chain
    /// reaches the stage's own error.
    #[test]
    fn a_stage_keeps_its_error_as_the_cause() {
        use std::error::Error;
        let inner = depthsense_prep::error::PrepError::BenchNoKeyframes;
        let e = ExperimentError::Stage {
            stage: "prepare",
            source: Box::new(inner),
        };
        assert_eq!(
            e.to_string(),
            "prepare: the bench world needs at least one keyframe"
        );
        let cause = e.source().unwrap();
        assert!(cause
            .downcast_ref::<depthsense_prep::error::PrepError>()
            .is_some());
    }

    /// What the layers below report comes through with its own message.
    #[test]
    fn errors_below_keep_their_messages() {
        let net = NetError::GradientsNotAttached;
        let text = net.to_string();
        assert_eq!(ExperimentError::from(net).to_string(), text);
        let e = ExperimentError::from(depthsense_config::ConfigError::UnknownVariant("x".into()));
        assert!(
            matches!(e, ExperimentError::Net(NetError::Request(_))),
            "{e}"
        );
    }
}
