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
use depthsense_config::ModelConfig;
use depthsense_config::RadarInput;
use depthsense_data::TargetKind;
use depthsense_dataset::Partition;
use depthsense_metrics::EvalConfig;
use serde::{Deserialize, Serialize};
use tch::nn::VarStore;

use depthsense_infer::NetError;

mod session;
use depthsense_infer::run::validate_net;
pub use session::{removing_new_folder_on_failure, train, train_distributed, Opened, Trainer};

use crate::metrics_log::{append_jsonl, truncate_metrics, write_curves, ValRecord};
use depthsense_infer::upload::upload_batch;

/// Everything a training run is made of. Defaults are the paper's (SPEC §8).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainOptions {
    pub data: PathBuf,
    pub out: PathBuf,
    /// The command line that started the run (its words, program first), recorded in
    /// RUN/config.json as `"command"` (empty: not recorded, e.g. a run an experiment made).
    #[serde(skip)]
    pub command: Vec<String>,
    pub model: ModelConfig,
    pub epochs: usize,
    pub batch_size: usize,
    pub lr: f64,
    /// Power of the polynomial decay (0.9).
    pub lr_power: f64,
    pub momentum: f64,
    pub weight_decay: f64,
    pub seed: u64,
    /// auto | cpu | cuda | cuda:N
    pub device: String,
    /// bf16 autocast of the forward pass (CUDA only).
    pub amp: bool,
    /// torchvision ResNet state dict for the RGB encoder (ImageNet initialisation).
    pub backbone_weights: Option<PathBuf>,
    /// Continue from RUN/last.safetensors.
    pub resume: bool,
    /// Loader threads (0 = all cores) and batches decoded ahead.
    pub jobs: usize,
    pub prefetch: usize,
    /// Radar map(s) feeding the radar channels (None = derive from the model config).
    pub radar_input: Option<RadarInput>,
    pub target: TargetKind,
    /// SPEC §8 augmentation.
    pub augment: bool,
    /// Without train/test split lists, every N-th scene (sorted by name) is held out.
    pub val_every_scene: usize,
    /// Use at most this many validation samples (evenly spaced), None = all.
    pub max_val_samples: Option<usize>,
    /// Use at most this many batches per epoch, None = all (quick runs).
    pub max_batches_per_epoch: Option<usize>,
    /// Save RUN/last.safetensors every N iterations as well as at each epoch end (0 = never).
    pub checkpoint_every: u64,
    /// Stop (after checkpointing) when this global iteration is reached — an interruption
    /// that `--resume` continues from exactly.
    pub stop_after: Option<u64>,
    /// Validation metric settings (caps, protocol, aggregation).
    pub eval: EvalConfig,
    /// Training scenes withheld per condition (SPEC §10.5; rule in
    /// `experiments::reduced_data`). Absent from the JSON when empty.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub exclude: Vec<depthsense_data::exclusion::Exclusion>,
    /// Read the training losses to the host every N iterations (one synchronisation per N on
    /// CUDA; always before a checkpoint, a stop and the epoch end). 0 = automatic: 1 on the CPU
    /// and in data-parallel jobs, [`CUDA_LOSS_READ_EVERY`] on CUDA. Absent from the JSON when 0.
    #[serde(default, skip_serializing_if = "depthsense_data::is_default")]
    pub loss_read_every: u64,
    /// Training-time radar dropout: each training sample loses a fraction U(0, p) of its
    /// radar returns ([`depthsense_data::LoadOptions::train_radar_drop`]). 0 = off (the paper).
    /// Absent from the JSON when 0.
    #[serde(default, skip_serializing_if = "depthsense_data::is_default")]
    pub train_radar_drop: f64,
    /// The oracle radar (issue 34; [`depthsense_data::radar_oracle`]): every radar return's
    /// depth replaced by the lidar target's, in training, validation and the experiments'
    /// test runs. An upper bound, not a model. Absent from the JSON when false.
    #[serde(default, skip_serializing_if = "depthsense_data::is_default")]
    pub radar_oracle: bool,
    /// Linear learning-rate warmup over the first N iterations before the poly decay (0 = none,
    /// the paper). Absent from the JSON when 0.
    #[serde(default, skip_serializing_if = "depthsense_data::is_default")]
    pub warmup_iters: u64,
    /// Start over in a folder that holds a run (its run files are removed first); without it
    /// such a folder is refused unless `resume` ([`crate::outputs`]). Absent from the JSON
    /// when false.
    #[serde(default, skip_serializing_if = "depthsense_data::is_default")]
    pub force: bool,
    /// `--init-from`: the weights a fresh network starts from (fine-tuning): a depthsense
    /// checkpoint, an `export --format pytorch` file or the authors' `.pth` (with the
    /// `released` config). Tensors of the network that the file lacks keep their
    /// initialisation; the report names them. Absent from the JSON when not given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init_from: Option<PathBuf>,
    /// `--extend`: continue the run in `out` from its last checkpoint to `epochs` epochs with a
    /// new learning-rate schedule from there (`lr`, poly decay to 0 at the new end), recorded
    /// in RUN/config.json. Absent from the JSON when false.
    #[serde(default, skip_serializing_if = "depthsense_data::is_default")]
    pub extend: bool,
    /// Train on the first N training samples only, in a fixed order of the samples (a hash of
    /// their tokens), so that the subsets of growing N are nested and every seed and variant
    /// sees the same ones (`experiment data-scale`). Validation and test are unchanged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_subset: Option<usize>,
    /// Each epoch is this many iterations, drawn from consecutive passes over the training
    /// samples (each pass a fresh shuffle), whatever their number: so runs on 100 or 3,000
    /// images take the same iterations and validate as often (`experiment data-scale`). None:
    /// an epoch is one pass.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub epoch_iterations: Option<u64>,
}

/// Iterations between loss reads on CUDA by default ([`TrainOptions::loss_read_every`] = 0).
pub const CUDA_LOSS_READ_EVERY: u64 = 25;

impl Default for TrainOptions {
    fn default() -> Self {
        Self {
            data: PathBuf::from("prepared"),
            out: PathBuf::from("runs/train"),
            command: Vec::new(),
            model: ModelConfig::paper(),
            epochs: 40,
            batch_size: 8,
            lr: 1e-3,
            lr_power: 0.9,
            momentum: 0.9,
            weight_decay: 1e-4,
            seed: 0,
            device: "auto".into(),
            amp: false,
            backbone_weights: None,
            resume: false,
            jobs: 0,
            prefetch: 4,
            radar_input: None,
            target: TargetKind::Dense,
            augment: true,
            val_every_scene: 5,
            max_val_samples: None,
            max_batches_per_epoch: None,
            checkpoint_every: 0,
            stop_after: None,
            eval: EvalConfig::default(),
            exclude: Vec::new(),
            loss_read_every: 0,
            train_radar_drop: 0.0,
            radar_oracle: false,
            warmup_iters: 0,
            force: false,
            init_from: None,
            extend: false,
            train_subset: None,
            epoch_iterations: None,
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
