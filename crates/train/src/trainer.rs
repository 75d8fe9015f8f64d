//! Training (SPEC §8): SGD with momentum, poly learning-rate decay per iteration, validation
//! each epoch, atomic checkpoints, exact resume, non-finite-loss stop.
//!
//! `RUN/` layout:
//! ```text
//! RUN/config.json            TrainOptions + ModelConfig + partition (held-out scenes)
//! RUN/metrics.jsonl          {"kind":"iter",…} per iteration, {"kind":"epoch",…} per epoch
//! RUN/curves.png             training loss and validation RMSE curves
//! RUN/last.safetensors       latest checkpoint (+ last.optim.safetensors: momentum buffers)
//! RUN/best.safetensors       lowest validation RMSE so far
//! ```

use std::path::{Path, PathBuf};

use depthsense_checkpoint as checkpoint;
use depthsense_config::training::{
    CheckpointOptions, ExtendOptions, HardwareOptions, LoadingOptions, ScheduleOptions,
    ValidationOptions,
};
use depthsense_config::ModelConfig;
use depthsense_config::RadarInput;
use depthsense_dataset::Partition;
use depthsense_metrics::EvalConfig;
use serde::{Deserialize, Serialize};
use tch::nn::VarStore;

use depthsense_infer::NetError;

mod session;
use depthsense_infer::run::validate_net;
pub use session::{removing_new_folder_on_failure, train, train_distributed, Opened, Trainer};

use crate::metrics_log::{write_curves, ValRecord};
use depthsense_infer::upload::upload_batch;

/// Everything a training run is made of. Defaults are the paper's (SPEC §8), written once, in
/// the option groups' flags ([`depthsense_config::training`]); RUN/config.json's `"train"`
/// holds the groups' fields flat, as it always did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainOptions {
    pub data: PathBuf,
    pub out: PathBuf,
    /// The command line that started the run (its words, program first), recorded in
    /// RUN/config.json as `"command"` (empty: not recorded, e.g. a run an experiment made).
    #[serde(skip)]
    pub command: Vec<String>,
    pub model: ModelConfig,
    #[serde(flatten)]
    pub schedule: ScheduleOptions,
    #[serde(flatten)]
    pub loading: LoadingOptions,
    #[serde(flatten)]
    pub validation: ValidationOptions,
    #[serde(flatten)]
    pub checkpointing: CheckpointOptions,
    #[serde(flatten)]
    pub extension: ExtendOptions,
    #[serde(flatten)]
    pub hardware: HardwareOptions,
    /// torchvision ResNet state dict for the RGB encoder (ImageNet initialisation).
    pub backbone_weights: Option<PathBuf>,
    /// Radar map(s) feeding the radar channels (None = derive from the model config).
    pub radar_input: Option<RadarInput>,
    /// Validation metric settings (caps, protocol, aggregation).
    pub eval: EvalConfig,
    /// Training scenes withheld per condition (SPEC §10.5; rule in
    /// `experiments::reduced_data`). Absent from the JSON when empty.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub exclude: Vec<depthsense_data::exclusion::Exclusion>,
    /// `--init-from`: the weights a fresh network starts from (fine-tuning): a depthsense
    /// checkpoint, an `export --format pytorch` file or the authors' `.pth` (with the
    /// `released` config). Tensors of the network that the file lacks keep their
    /// initialisation; the report names them. Absent from the JSON when not given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init_from: Option<PathBuf>,
}

pub use depthsense_config::training::CUDA_LOSS_READ_EVERY;

impl Default for TrainOptions {
    fn default() -> Self {
        Self {
            data: PathBuf::from("prepared"),
            out: PathBuf::from("runs/train"),
            command: Vec::new(),
            model: ModelConfig::paper(),
            schedule: ScheduleOptions::default(),
            loading: LoadingOptions::default(),
            validation: ValidationOptions::default(),
            checkpointing: CheckpointOptions::default(),
            extension: ExtendOptions::default(),
            hardware: HardwareOptions::default(),
            backbone_weights: None,
            radar_input: None,
            eval: EvalConfig::default(),
            exclude: Vec::new(),
            init_from: None,
        }
    }
}

/// What a (possibly partial) training invocation did.
#[derive(Debug, Clone)]
pub struct TrainSummary {
    pub run_dir: PathBuf,
    /// (global iteration, loss) of the iterations run by this invocation.
    pub losses: Vec<(u64, f64)>,
    /// Validation before training (iteration 0, when not resuming) and after each epoch.
    pub val: Vec<ValRecord>,
    pub iterations_done: u64,
    pub total_iterations: u64,
    /// True when `stop_after` or a stop signal interrupted the run.
    pub interrupted: bool,
    /// The stop signal (SIGINT / SIGTERM) that interrupted it, checkpointed first.
    pub signal: Option<depthsense_base::interrupt::StopSignal>,
    /// `--resume` of a run that had done all its epochs: nothing was trained or changed.
    pub already_finished: Option<FinishedRun>,
    pub best_val_rmse: f64,
    /// What RUN/best.safetensors holds and whether this invocation wrote it.
    pub best: BestCheckpoint,
    /// Images per second of the training steps alone (`images / train_seconds`).
    pub train_images_per_s: f64,
    /// Seconds in training steps, loader waits included (this invocation).
    pub train_seconds: f64,
    /// Seconds in validation (this invocation).
    pub val_seconds: f64,
    /// Wall seconds from opening the data to the end, so also set-up and checkpoints.
    pub seconds: f64,
    pub partition: Partition,
    /// Validation samples each validation scores (`--max-val-samples` of the partition's).
    pub val_samples_used: usize,
}

/// A run that `--resume` found finished (all its epochs done): an outcome, said to the user,
/// not an error.
#[derive(Debug, Clone, PartialEq)]
pub struct FinishedRun {
    pub run: PathBuf,
    pub epochs: usize,
    pub iteration: u64,
}

impl std::fmt::Display for FinishedRun {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (run, epochs, iteration) = (self.run.display(), self.epochs, self.iteration);
        write!(
            f,
            "{run} is finished: {epochs} of {epochs} epochs (iteration {iteration}); nothing was \
             changed. To train it longer, run the same command with --extend --epochs N (N > \
             {epochs}): a new learning-rate schedule from its last checkpoint \
             (docs/guide/train.md, \"Longer runs and fine-tuning\")"
        )
    }
}

/// What RUN/best.safetensors holds: the network of the lowest validation RMSE of the run, the
/// validation before training included (so a fine-tuning or an extension that only makes the
/// network worse keeps the weights it started from).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BestCheckpoint {
    /// Its validation RMSE (m); `None` before any validation.
    pub val_rmse: Option<f64>,
    /// Its iteration and epoch (0: the network before training); `None` for a checkpoint
    /// written before they were recorded.
    pub iteration: Option<u64>,
    pub epoch: Option<u64>,
    /// Whether this invocation wrote it (false: an earlier invocation's, e.g. before
    /// `--extend` or `--resume`).
    pub written_by_this_run: bool,
}

impl std::fmt::Display for BestCheckpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let Some(rmse) = self.val_rmse else {
            return write!(f, "best.safetensors: none yet (no validation finished)");
        };
        write!(f, "best.safetensors: ")?;
        match (self.iteration, self.epoch) {
            (Some(0), _) => write!(f, "the network before training (iteration 0)")?,
            (Some(it), Some(e)) => write!(f, "epoch {e} (iteration {it})")?,
            _ => write!(f, "an epoch not recorded (an older checkpoint)")?,
        }
        write!(f, ", validation RMSE {rmse:.3} m; ")?;
        if self.written_by_this_run {
            write!(f, "written by this run")
        } else {
            write!(f, "unchanged by this run (no validation beat it)")
        }
    }
}

/// Training state stored in a checkpoint's `extra` (with the options that must not change
/// across a resume).
#[derive(Debug, Clone, Serialize, Deserialize)]
struct State {
    kind: String,
    iteration: u64,
    epoch: u64,
    seed: u64,
    /// Lowest validation RMSE so far, the validation before training included; `None` before
    /// any validation (JSON has no ∞).
    best_val_rmse: Option<f64>,
    /// The iteration and epoch of RUN/best.safetensors (`None` in checkpoints written before
    /// they were recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    best_iteration: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    best_epoch: Option<u64>,
    batch_size: usize,
    epochs: usize,
    /// The learning rate of the current schedule segment (the run's `--lr`, or the last
    /// `--extend`'s).
    lr: f64,
    val_rmse: Option<f64>,
    /// The learning-rate schedule in segments: empty for a run never extended (one poly decay
    /// over the whole run); one segment more per `--extend`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    schedule: Vec<Segment>,
    /// What `--init-from` loaded into the fresh network (kept across resumes for config.json).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    init_from: Option<serde_json::Value>,
    /// The map settings of the prepared data it is trained on (`index.json`'s `settings`:
    /// radar sweeps, channels, filters, velocity compensation, …), so that `predict` and
    /// `export` can tell what radar input the network expects.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    data_settings: std::collections::BTreeMap<String, serde_json::Value>,
}

impl State {
    /// The schedule values this checkpoint was trained with, which an exact resume keeps.
    fn schedule_key(&self) -> depthsense_config::refusal::ScheduleKey {
        depthsense_config::refusal::ScheduleKey {
            batch_size: self.batch_size,
            epochs: self.epochs,
            lr: self.lr,
            seed: self.seed,
        }
    }
}

/// One segment of the learning-rate schedule: a poly decay from `lr` at `start_iteration` to 0
/// at `end_iteration` (after `warmup` iterations of linear warmup).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Segment {
    pub start_iteration: u64,
    pub end_iteration: u64,
    pub lr: f64,
    #[serde(default, skip_serializing_if = "depthsense_data::is_default")]
    pub warmup: u64,
}

use depthsense_dataset::subsample;

fn all_finite(vs: &VarStore) -> bool {
    tch::no_grad(|| {
        vs.variables().values().all(|t| {
            if !t.is_floating_point() {
                return true;
            }
            t.isfinite().all().int64_value(&[]) == 1
        })
    })
}

fn save_ckpt(
    path: &Path,
    vs: &VarStore,
    cfg: &ModelConfig,
    state: &State,
    opts: &TrainOptions,
) -> Result<(), NetError> {
    let extra = serde_json::json!({
        "train_state": state,
        "train_options": opts,
    });
    checkpoint::save(path, vs, cfg, &extra)?;
    Ok(())
}
