//! depthsense-mer-train (layer 7, ARCHITECTURE.md) — `depthsense mer train`: the PDA association network (SPEC §5) on the `train` split, with
//! validation on `val` (precision / recall at 0.5 and ROC AUC of the associations), the same
//! run-directory conventions as `train`:
//!
//! ```text
//! RUN/config.json          options, PDA config, partition
//! RUN/metrics.jsonl        {"kind":"iter"} per iteration, {"kind":"epoch","val":…} per epoch
//! RUN/curves.png           training loss and validation AUC
//! RUN/last.safetensors     latest PDA checkpoint (+ last.optim.safetensors: momentum)
//! RUN/best.safetensors     highest validation AUC
//! ```
//! Optimiser: Adam with poly learning-rate decay ([`depthsense_train::adam`],
//! [`depthsense_train::schedule`]), whose state is saved, so that `--resume` continues exactly
//! from the last checkpoint — an epoch's end, or inside an epoch where `--stop-after` stopped
//! it. The run is a [`Learner`] driven step by step by the training engine's loop
//! ([`depthsense_train::learner::fit`]), with its run-folder lock and checkpointer.

use std::path::{Path, PathBuf};
use std::time::Instant;

use depthsense_base::fsutil::write_atomic;
use depthsense_config::device::DeviceArg;
use depthsense_config::mer_training::{MerLoadingOptions, MerScheduleOptions};
use depthsense_config::pda::PdaConfig;
use depthsense_config::refusal::{ConfigDifference, ScheduleKey, TrainingRefusal};
use depthsense_config::training::{CheckpointOptions, ValidationOptions};
use depthsense_data::{epoch_order, sample_rng};
use depthsense_dataset::outputs::{
    BEST_CKPT, CONFIG_FILE, CURVES_FILE, LAST_CKPT, LAST_OPTIM, METRICS_FILE,
};
use depthsense_dataset::subsample;
use depthsense_dataset::{partition, Dataset};
use depthsense_infer::NetError;
use depthsense_model::pda::{self, balanced_bce, PdaNet};
use depthsense_prep::layout::IndexEntry;
use depthsense_progress::Progress;
use depthsense_records::convert;
use depthsense_records::metrics_log::MetricsRecord;
use depthsense_records::run_config::{Command, MerRunConfig, RUN_CONFIG_VERSION};
use depthsense_train::adam::Adam;
use depthsense_train::learner::{fit, Batches, Checkpointer, EpochTiming, Learner, Plan, StepDone};
use depthsense_train::metrics_log::{logged_loss_sum, EpochRecord, IterRecord};
use depthsense_train::optim::Optimizer;
use depthsense_train::run_folder::RunFolder;
use depthsense_train::schedule::{poly_lr, seed_step};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use tch::{nn::VarStore, Device, Kind, Tensor};

use depthsense_mer::labels::{load_labelled, PdaInput};

/// Options of `mer train`: its own option groups and `train`'s validation and checkpointing
/// groups (`depthsense_config::{mer_training, training}`), flattened: RUN/config.json's
/// `"mer_train"` keeps flat keys.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MerTrainOptions {
    pub data: PathBuf,
    pub out: PathBuf,
    pub pda: PdaConfig,
    #[serde(flatten)]
    pub schedule: MerScheduleOptions,
    #[serde(flatten)]
    pub loading: MerLoadingOptions,
    #[serde(flatten)]
    pub validation: ValidationOptions,
    #[serde(flatten)]
    pub checkpointing: CheckpointOptions,
    #[serde(flatten)]
    pub device: DeviceArg,
    /// The command line that started the run (its words, program first), recorded in
    /// RUN/config.json as `"command"` (empty: not recorded).
    #[serde(skip)]
    pub command: Vec<String>,
}

impl Default for MerTrainOptions {
    fn default() -> Self {
        Self {
            data: PathBuf::from("prepared"),
            out: PathBuf::from("runs/mer"),
            pda: PdaConfig::paper(),
            schedule: MerScheduleOptions::default(),
            loading: MerLoadingOptions::default(),
            validation: ValidationOptions::default(),
            checkpointing: CheckpointOptions::default(),
            device: DeviceArg::default(),
            command: Vec::new(),
        }
    }
}

/// Validation of the associations over every labelled (radar pixel, neighbour) pair (the
/// record metrics.jsonl holds, `depthsense_records`').
pub use depthsense_records::metrics_log::PdaValRecord as MerValRecord;

/// What `mer train` did.
#[derive(Debug, Clone)]
pub struct MerTrainSummary {
    pub run_dir: PathBuf,
    pub val: Vec<MerValRecord>,
    pub best_auc: f64,
    /// The iteration of RUN/best.safetensors (0: the network before training).
    pub best_iteration: Option<u64>,
    pub parameters: i64,
    pub iterations: u64,
    pub seconds: f64,
    /// Stopped at `stop_after` or by a stop signal before the last epoch's end.
    pub interrupted: bool,
    /// The stop signal (SIGINT / SIGTERM) that interrupted it, checkpointed first.
    pub signal: Option<depthsense_base::interrupt::StopSignal>,
    /// Iterations of the whole run.
    pub total_iterations: u64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct State {
    kind: String,
    epoch: u64,
    iteration: u64,
    seed: u64,
    batch_size: usize,
    epochs: usize,
    lr: f64,
    best_auc: Option<f64>,
    /// The iteration of RUN/best.safetensors (`None` in checkpoints written before it was
    /// recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    best_iteration: Option<u64>,
}

impl State {
    /// The schedule values this checkpoint was trained with, which an exact resume keeps.
    fn schedule_key(&self) -> ScheduleKey {
        ScheduleKey {
            batch_size: self.batch_size,
            epochs: self.epochs,
            lr: self.lr,
            seed: self.seed,
        }
    }
}

/// A batch on the device: image `[B,3,h,w]`, radar `[B,1,h,w]`, flat radar-pixel indices
/// `[N]`, labels and mask `[N,K]`.
struct PdaBatch {
    image: Tensor,
    radar: Tensor,
    idx: Tensor,
    labels: Tensor,
    mask: Tensor,
    n: usize,
}

fn stack(samples: &[(PdaInput, Vec<i8>)], device: Device) -> Result<PdaBatch, NetError> {
    let g = samples[0].0.grid;
    if let Some((s, _)) = samples.iter().find(|(s, _)| s.grid != g) {
        return Err(NetError::MerGridsDiffer {
            first: (g.w, g.h),
            other: (s.grid.w, s.grid.h),
        });
    }
    let b = samples.len() as i64;
    let (h, w) = (g.h as i64, g.w as i64);
    let image: Vec<f32> = samples.iter().flat_map(|(s, _)| s.image.clone()).collect();
    let radar: Vec<f32> = samples.iter().flat_map(|(s, _)| s.radar.clone()).collect();
    let mut idx = vec![];
    let mut lab = vec![];
    for (bi, (s, l)) in samples.iter().enumerate() {
        idx.extend(
            s.pixels
                .iter()
                .map(|p| (bi * g.len() + p.v * g.w + p.u) as i64),
        );
        lab.extend_from_slice(l);
    }
    let k = if idx.is_empty() {
        1
    } else {
        lab.len() / idx.len()
    } as i64;
    let labels: Vec<f32> = lab.iter().map(|&x| (x == 1) as u8 as f32).collect();
    let mask: Vec<f32> = lab.iter().map(|&x| (x >= 0) as u8 as f32).collect();
    let n = idx.len();
    Ok(PdaBatch {
        image: Tensor::from_slice(&image)
            .view([b, 3, h, w])
            .to_device(device),
        radar: Tensor::from_slice(&radar)
            .view([b, 1, h, w])
            .to_device(device),
        idx: Tensor::from_slice(&idx).to_device(device),
        labels: Tensor::from_slice(&labels)
            .view([n as i64, k])
            .to_device(device),
        mask: Tensor::from_slice(&mask)
            .view([n as i64, k])
            .to_device(device),
        n,
    })
}

/// Reads labelled samples in parallel on `pool`.
fn load_group(
    ds: &Dataset,
    entries: &[&IndexEntry],
    flips: &[bool],
    cfg: &PdaConfig,
    pool: &rayon::ThreadPool,
) -> Result<Vec<(PdaInput, Vec<i8>)>, NetError> {
    pool.install(|| {
        entries
            .par_iter()
            .zip(flips)
            .map(|(e, &f)| load_labelled(&ds.sample_dir(e), cfg, f))
            .collect()
    })
}

/// Loss of a batch (None when it holds no labelled pair) and the network output at its
/// radar pixels.
fn batch_loss(net: &PdaNet, b: &PdaBatch, train: bool) -> Option<(Tensor, Tensor)> {
    if b.n == 0 || b.mask.sum(Kind::Float).double_value(&[]) == 0.0 {
        return None;
    }
    let f = net.features_t(&b.image, &b.radar, train);
    let sel = net.logits_at(&f, &b.idx);
    Some((balanced_bce(&sel, &b.labels, &b.mask), sel))
}

/// ROC AUC of (score, label) pairs: the probability that a random positive scores above a
/// random negative, ties ½ (Mann–Whitney). NaN without both classes.
pub fn roc_auc(pairs: &mut [(f32, bool)]) -> f64 {
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n_pos = pairs.iter().filter(|p| p.1).count() as f64;
    let n_neg = pairs.len() as f64 - n_pos;
    if n_pos == 0.0 || n_neg == 0.0 {
        return f64::NAN;
    }
    // Sum of (average) ranks of the positives.
    let (mut i, mut rank_sum) = (0usize, 0f64);
    while i < pairs.len() {
        let mut j = i;
        while j < pairs.len() && pairs[j].0 == pairs[i].0 {
            j += 1;
        }
        let avg = (i + j + 1) as f64 / 2.0; // ranks i+1..=j
        rank_sum += avg * pairs[i..j].iter().filter(|p| p.1).count() as f64;
        i = j;
    }
    (rank_sum - n_pos * (n_pos + 1.0) / 2.0) / (n_pos * n_neg)
}

/// Precision and recall of `score > threshold` (NaN when undefined).
pub fn precision_recall(pairs: &[(f32, bool)], threshold: f32) -> (f64, f64) {
    let tp = pairs.iter().filter(|p| p.1 && p.0 > threshold).count() as f64;
    let fp = pairs.iter().filter(|p| !p.1 && p.0 > threshold).count() as f64;
    let pos = pairs.iter().filter(|p| p.1).count() as f64;
    (tp / (tp + fp), tp / pos)
}

/// Validation metrics of `net` on `entries`.
pub fn validate_pda(
    net: &PdaNet,
    ds: &Dataset,
    entries: &[IndexEntry],
    batch_size: usize,
    pool: &rayon::ThreadPool,
    device: Device,
) -> Result<MerValRecord, NetError> {
    let cfg = net.config();
    let mut pairs: Vec<(f32, bool)> = vec![];
    let (mut loss, mut nb) = (0.0, 0usize);
    for chunk in entries.chunks(batch_size.max(1)) {
        let refs: Vec<&IndexEntry> = chunk.iter().collect();
        let samples = load_group(ds, &refs, &vec![false; refs.len()], cfg, pool)?;
        let b = stack(&samples, device)?;
        let Some((l, sel)) = tch::no_grad(|| batch_loss(net, &b, false)) else {
            continue;
        };
        loss += l.double_value(&[]);
        nb += 1;
        let p = Vec::<f32>::try_from(sel.sigmoid().to_device(Device::Cpu).view([-1]))?;
        let y = Vec::<f32>::try_from(b.labels.to_device(Device::Cpu).view([-1]))?;
        let m = Vec::<f32>::try_from(b.mask.to_device(Device::Cpu).view([-1]))?;
        pairs.extend(
            p.iter()
                .zip(&y)
                .zip(&m)
                .filter(|(_, &m)| m > 0.0)
                .map(|((&p, &y), _)| (p, y > 0.5)),
        );
    }
    let (precision, recall) = precision_recall(&pairs, 0.5);
    let positives = pairs.iter().filter(|p| p.1).count() as u64;
    Ok(MerValRecord {
        epoch: 0,
        iteration: 0,
        loss: loss / nb.max(1) as f64,
        precision,
        recall,
        auc: roc_auc(&mut pairs),
        pairs: pairs.len() as u64,
        positives,
    })
}

/// A training run of the PDA network in progress.
struct Run<'o> {
    opts: &'o MerTrainOptions,
    device: Device,
    ds: Dataset,
    train: Vec<IndexEntry>,
    val: Vec<IndexEntry>,
    vs: VarStore,
    net: PdaNet,
    optim: Adam,
    state: State,
    pool: rayon::ThreadPool,
    bpe: u64,
    /// The run folder's lock, held while the run writes there.
    folder: RunFolder,
    /// RUN/last.safetensors with its optimiser state.
    ckpt: Checkpointer,
    /// The current epoch's loss: (sum, steps).
    epoch_loss: (f64, usize),
    /// When this invocation began.
    started: Instant,
    /// The last step's loss and learning rate (the progress line).
    last_loss: Option<(f64, f64)>,
}

impl<'o> Run<'o> {
    /// What the run trains on and for how long (the first line of its log).
    fn start_line(&self) -> String {
        let o = self.opts;
        let from = match self.state.iteration {
            0 => String::new(),
            it => format!(", resumed at iteration {it}"),
        };
        format!(
            "PDA on {} training / {} validation samples of {}; {} epochs × {} iterations, \
             batch {}, lr {}, {}{from} → {}",
            self.train.len(),
            self.val.len(),
            o.data.display(),
            o.schedule.epochs,
            self.bpe,
            o.schedule.batch_size,
            o.schedule.lr,
            depthsense_model::device::describe(self.device),
            o.out.display()
        )
    }

    fn new(opts: &'o MerTrainOptions) -> Result<Self, NetError> {
        let started = Instant::now();
        opts.schedule.check()?;
        let device = depthsense_model::device::parse_device(&opts.device.name)?;
        let ds = Dataset::open(&opts.data)?;
        let part = partition(&ds, opts.validation.val_every_scene)?;
        part.require_train_and_val(&opts.data)?;
        // One writer per run folder; a run there is refused unless --resume or --force.
        let folder = RunFolder::take(
            &opts.out,
            "mer train",
            opts.checkpointing.resume,
            opts.checkpointing.force,
        )?;
        let jobs = depthsense_data::loader_threads(opts.loading.jobs);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(jobs)
            .build()
            .map_err(|e| depthsense_dataset::DataError::thread_start("loader threads", e))?;
        let (vs, net, optim, state, optim_matches) = build(opts, device)?;
        folder.restart_log(state.iteration)?;
        let bpe = opts.schedule.iterations_per_epoch(part.train.len());
        let run = Run {
            opts,
            device,
            ds,
            val: subsample(&part.val, opts.validation.max_val_samples),
            train: part.train.clone(),
            vs,
            net,
            optim,
            state,
            pool,
            bpe,
            folder,
            ckpt: Checkpointer::new(&opts.out, optim_matches),
            epoch_loss: (0.0, 0),
            started,
            last_loss: None,
        };
        run.write_config(&part)?;
        Ok(run)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.opts.out.join(name)
    }

    fn write_config(&self, part: &depthsense_dataset::Partition) -> Result<(), NetError> {
        let p = self.path(CONFIG_FILE);
        let record = |e: depthsense_records::RecordError| NetError::Parse {
            path: e.path.clone(),
            reason: e.reason(),
        };
        let config = MerRunConfig {
            format_version: RUN_CONFIG_VERSION,
            mer_train: convert(self.opts, &p).map_err(record)?,
            pda: Some(serde_json::to_value(&self.opts.pda)?),
            parameters: Some(pda::parameter_count(&self.vs) as u64),
            device: Some(depthsense_model::device::describe(self.device)),
            partition: Some(
                convert(
                    &serde_json::json!({"method": part.method, "train_samples": part.train.len(),
                          "val_samples": part.val.len(), "val_samples_used": self.val.len(),
                          "val_scenes": part.val_scenes}),
                    &p,
                )
                .map_err(record)?,
            ),
            command: Command::of_words(&self.opts.command),
        };
        self.folder.write_config(&config)
    }

    /// What a checkpoint stores beside the weights: the run's state and options.
    fn checkpoint_extra(&self) -> serde_json::Value {
        serde_json::json!({"train_state": self.state, "mer_train": self.opts})
    }

    fn save(&self, name: &str) -> Result<(), NetError> {
        depthsense_checkpoint::pda::save(
            &self.path(name),
            &self.vs,
            &self.opts.pda,
            &self.checkpoint_extra(),
        )?;
        Ok(())
    }

    /// The batches (training-sample indices) of epoch `epoch` after its first `skip`; the
    /// epoch's loss starts with the losses logged before a resume.
    fn epoch_batches(&mut self, epoch: u64, skip: u64) -> Vec<Vec<usize>> {
        let o = self.opts;
        let order = epoch_order(self.train.len(), o.schedule.seed, epoch, true);
        self.epoch_loss = (0.0, 0);
        if skip > 0 {
            let path = self.path(METRICS_FILE);
            self.epoch_loss = logged_loss_sum(&path, epoch * self.bpe, self.state.iteration);
        }
        order
            .chunks(o.schedule.batch_size)
            .take(self.bpe as usize)
            .skip(skip as usize)
            .map(<[usize]>::to_vec)
            .collect()
    }

    /// One Adam step on the training samples `chunk`; a batch without a labelled pair counts
    /// as an iteration without an update.
    fn adam_step(&mut self, chunk: &[usize], epoch: u64) -> Result<u64, NetError> {
        let o = self.opts;
        let refs: Vec<&IndexEntry> = chunk.iter().map(|&i| &self.train[i]).collect();
        let flips: Vec<bool> = chunk
            .iter()
            .map(|&i| o.loading.augment && sample_rng(o.schedule.seed, epoch, i).uniform() < 0.5)
            .collect();
        let samples = load_group(&self.ds, &refs, &flips, &o.pda, &self.pool)?;
        let b = stack(&samples, self.device)?;
        let total = self.plan().total_iterations();
        let lr = poly_lr(
            o.schedule.lr,
            self.state.iteration,
            total,
            o.schedule.lr_power,
        );
        seed_step(o.schedule.seed, self.state.iteration);
        self.state.iteration += 1;
        let it = self.state.iteration;
        let Some((loss, _)) = batch_loss(&self.net, &b, true) else {
            return Ok(it);
        };
        let lv = loss.double_value(&[]);
        if !lv.is_finite() {
            return Err(NetError::NonFiniteLoss {
                loss: lv,
                epoch,
                iteration: it,
                kept: self.path(LAST_CKPT).display().to_string(),
            });
        }
        self.optim.zero_grad();
        loss.backward();
        self.optim.step(lr);
        self.epoch_loss = (self.epoch_loss.0 + lv, self.epoch_loss.1 + 1);
        self.folder
            .append::<MerValRecord>(&MetricsRecord::Iter(IterRecord::new(epoch, it, lv, lr)))?;
        self.last_loss = Some((lv, lr));
        Ok(it)
    }

    /// RUN/last.safetensors and its optimiser state: the state's predecessor is kept until the
    /// checkpoint is written (optim_state::rotate), so a kill anywhere leaves a resumable pair.
    fn write_last(&mut self) -> Result<(), NetError> {
        let extra = self.checkpoint_extra();
        let (vs, pda_cfg, iteration) = (&self.vs, &self.opts.pda, self.state.iteration);
        let optim = &self.optim;
        self.ckpt.save_last(
            |path| optim.save(path, iteration),
            |last| Ok(depthsense_checkpoint::pda::save(last, vs, pda_cfg, &extra)?),
        )
    }

    fn validate_at(&self, epoch: u64) -> Result<MerValRecord, NetError> {
        let mut v = validate_pda(
            &self.net,
            &self.ds,
            &self.val,
            self.opts.schedule.batch_size,
            &self.pool,
            self.device,
        )?;
        v.epoch = epoch;
        v.iteration = self.state.iteration;
        Ok(v)
    }

    /// Epoch `epoch`'s (0-based) record in RUN/metrics.jsonl, validated as `v`, and the curves.
    fn write_epoch_record(
        &mut self,
        epoch: u64,
        v: &MerValRecord,
        timing: &EpochTiming,
    ) -> Result<(), NetError> {
        let loss = self.epoch_loss.0 / self.epoch_loss.1.max(1) as f64;
        let it = self.state.iteration;
        self.folder
            .append(&MetricsRecord::Epoch(timing.stamp(EpochRecord::new(
                epoch + 1,
                it,
                loss,
                v.clone(),
            ))))?;
        write_curves(&self.path(METRICS_FILE), &self.path(CURVES_FILE))
    }
}

/// A fresh (seeded) network or the one of RUN/last.safetensors when resuming.
fn build(
    opts: &MerTrainOptions,
    device: Device,
) -> Result<(VarStore, PdaNet, Adam, State, bool), NetError> {
    let last = opts.out.join(LAST_CKPT);
    let mut state = State {
        kind: "depthsense-mer-train".into(),
        epoch: 0,
        iteration: 0,
        seed: opts.schedule.seed,
        batch_size: opts.schedule.batch_size,
        epochs: opts.schedule.epochs,
        lr: opts.schedule.lr,
        best_auc: None,
        best_iteration: None,
    };
    if !(opts.checkpointing.resume && last.exists()) {
        tch::manual_seed(opts.schedule.seed as i64);
        let vs = VarStore::new(device);
        let net = PdaNet::new(&vs.root(), &opts.pda)?;
        let optim = Adam::new(&vs, opts.schedule.weight_decay);
        return Ok((vs, net, optim, state, true));
    }
    let l = depthsense_checkpoint::pda::load(&last, device)?;
    let stored: State =
        serde_json::from_value(l.extra["train_state"].clone()).map_err(|e| NetError::Parse {
            path: last.to_path_buf(),
            reason: format!("train_state: {e}"),
        })?;
    if l.config != opts.pda || stored.schedule_key() != opts.schedule.key() {
        let mut differences = ConfigDifference::between_any(&l.config, &opts.pda);
        differences.extend(ConfigDifference::between_any(
            &stored.schedule_key(),
            &opts.schedule.key(),
        ));
        return Err(TrainingRefusal::OtherPdaRun {
            checkpoint: last,
            differences,
        }
        .into());
    }
    state = stored;
    let mut optim = Adam::new(&l.vs, opts.schedule.weight_decay);
    let matches = depthsense_train::optim_state::load_matching(
        &opts.out.join(LAST_OPTIM),
        &last,
        state.iteration,
        |p| optim.load(p),
    )?;
    Ok((l.vs, l.net, optim, state, matches))
}

/// RUN/curves.png: training loss (left) and validation AUC (right).
pub fn write_curves(metrics: &Path, png: &Path) -> Result<(), NetError> {
    let text = std::fs::read_to_string(metrics).map_err(|e| NetError::io(metrics, e))?;
    let (mut loss, mut auc) = (vec![], vec![]);
    for l in text.lines() {
        let Ok(v) = serde_json::from_str::<serde_json::Value>(l) else {
            continue;
        };
        let it = v["iteration"].as_u64().unwrap_or(0);
        match v["kind"].as_str() {
            Some("iter") => loss.push((it, v["loss"].as_f64().unwrap_or(f64::NAN))),
            Some("epoch") | Some("val") => {
                auc.push((it, v["val"]["auc"].as_f64().unwrap_or(f64::NAN)))
            }
            _ => {}
        }
    }
    let bytes = depthsense_viz::plot::curves_png_labelled(
        ("training loss", "loss", &[("train loss", &loss)]),
        ("validation", "AUC", &[("val AUC", &auc)]),
    )?;
    write_atomic(png, &bytes).map_err(|e| NetError::io(png, e))
}

impl Learner for Run<'_> {
    type Val = MerValRecord;
    type Batch = Vec<usize>;

    fn iteration(&self) -> u64 {
        self.state.iteration
    }

    fn started(&self) -> Instant {
        self.started
    }

    fn plan(&self) -> Plan {
        Plan {
            iterations_per_epoch: self.bpe,
            epochs: self.opts.schedule.epochs as u64,
            checkpoint_every: self.opts.checkpointing.checkpoint_every,
            stop_after: self.opts.checkpointing.stop_after,
        }
    }

    fn validation(&mut self, epoch: u64) -> Result<MerValRecord, NetError> {
        if epoch > 0 {
            self.state.iteration = epoch * self.bpe;
        }
        let v = self.validate_at(epoch)?;
        if epoch > 0 {
            self.state.epoch = epoch;
        }
        Ok(v)
    }

    /// Higher AUC is better.
    fn score(v: &MerValRecord) -> f64 {
        -v.auc
    }

    fn best_score(&self) -> Option<f64> {
        self.state.best_auc.map(|auc| -auc)
    }

    fn note_best(&mut self, v: &MerValRecord) {
        self.state.best_auc = Some(v.auc);
        self.state.best_iteration = Some(self.state.iteration);
    }

    fn save_best(&mut self) -> Result<(), NetError> {
        self.save(BEST_CKPT)
    }

    fn run_folder(&self) -> Option<&RunFolder> {
        Some(&self.folder)
    }

    fn batches(&mut self, epoch: u64, skip: u64) -> Result<Batches<Vec<usize>>, NetError> {
        Ok(Box::new(
            self.epoch_batches(epoch, skip).into_iter().map(Ok),
        ))
    }

    fn step(&mut self, chunk: Vec<usize>, epoch: u64, _: &Progress) -> Result<StepDone, NetError> {
        let iteration = self.adam_step(&chunk, epoch)?;
        Ok(StepDone {
            iteration,
            images: chunk.len() as u64,
        })
    }

    fn status(&self) -> String {
        depthsense_train::learner::loss_status(self.last_loss)
    }

    /// Losses are read at every step.
    fn flush(&mut self, _: u64, _: &Progress) -> Result<(), NetError> {
        Ok(())
    }

    fn save_last(&mut self, epoch: u64) -> Result<(), NetError> {
        self.state.epoch = epoch;
        self.write_last()
    }

    fn log_epoch(
        &mut self,
        epoch: u64,
        v: &MerValRecord,
        timing: &EpochTiming,
    ) -> Result<(), NetError> {
        self.write_epoch_record(epoch, v, timing)
    }
}

/// Train the PDA network (see the module docs for RUN/).
pub fn train_pda(opts: &MerTrainOptions, progress: &Progress) -> Result<MerTrainSummary, NetError> {
    depthsense_train::trainer::removing_new_folder_on_failure(&opts.out, || {
        let mut run = Run::new(opts)?;
        progress.println(run.start_line());
        let fitted = fit(&mut run, progress)?;
        Ok(MerTrainSummary {
            run_dir: opts.out.clone(),
            val: fitted.val,
            best_auc: run.state.best_auc.unwrap_or(f64::NAN),
            best_iteration: run.state.best_iteration,
            parameters: pda::parameter_count(&run.vs),
            iterations: run.state.iteration,
            seconds: fitted.clock.seconds(),
            interrupted: fitted.interrupted,
            signal: fitted.signal,
            total_iterations: run.plan().total_iterations(),
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auc_by_hand() {
        let mut p = vec![(0.9, true), (0.8, false), (0.7, true), (0.1, false)];
        assert!((roc_auc(&mut p) - 0.75).abs() < 1e-12);
        let mut ties = vec![(0.5, true), (0.5, false)];
        assert!((roc_auc(&mut ties) - 0.5).abs() < 1e-12);
        assert!(roc_auc(&mut [(0.3, true)]).is_nan());
        let (pr, rc) = precision_recall(&[(0.9, true), (0.6, false), (0.4, true)], 0.5);
        assert_eq!((pr, rc), (0.5, 0.5));
    }
}
