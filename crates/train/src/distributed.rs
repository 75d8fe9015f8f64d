//! Data-parallel training on several processes, GPUs and machines (c10d through
//! `depthsense-dist`): what [`crate::trainer::Trainer`] does differently when it is one rank
//! of a job.
//!
//! - **Start**: parameters and buffers are broadcast from rank 0 (sorted by name), so every
//!   replica starts identical (fresh or resumed).
//! - **Data**: `--batch-size` is the *global* batch; global batch i holds the same samples
//!   whatever the world size N is, and rank r takes the slice `[r·B/N, (r+1)·B/N)`
//!   ([`depthsense_data::Loader::start_shard`]); augmentation draws are per sample.
//! - **Step**: the loss of each rank is the mean over its slice; after backward the gradients
//!   are averaged over the ranks in ≈25 MB flat buckets (DDP's default), then every rank takes
//!   the same SGD step. The logged loss is the mean of the ranks' losses.
//! - **Dropout**: the head's Dropout2d masks are drawn per sample from (seed, iteration,
//!   place in the global batch), so they too do not depend on N (a single process without a
//!   job keeps libtorch's generator, as before).
//! - **BatchNorm**: without `--sync-bn` each rank normalises with its own slice's statistics
//!   and the running statistics are broadcast from rank 0 before each forward (DDP's
//!   `broadcast_buffers`); with `--sync-bn` the statistics are those of the global batch
//!   ([`depthsense_dist::sync_bn`], installed through `depthsense_model::sync_bn`), so a run
//!   on N ranks equals one process with the same global batch.
//! - **Validation**: each rank evaluates a contiguous shard of the validation samples; the
//!   reports are summed exactly (counts and weighted metric sums) and every rank gets the
//!   same record.
//! - **Files**: only rank 0 writes RUN/ (config, metrics, curves, checkpoints) and shows the
//!   progress bar. Checkpoints do not depend on N: `--resume` works with any world size.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::Arc;
use std::time::Duration;

use depthsense_dist::sync_bn::{batch_norm, BnState};
use depthsense_dist::{broadcast_flat, GradBuckets, ReduceOp};
use depthsense_metrics::{Aggregate, Metrics, Report};
use depthsense_model::sync_bn::{BatchNormHook, DropoutSeeds, TrainHooks};
use serde::{Deserialize, Serialize};
use tch::{nn, nn::ModuleT, nn::VarStore, Device, Kind, Tensor};

use depthsense_base::hash::splitmix64;
use depthsense_dist::{Backend, DistEnv, ProcessGroup, DEFAULT_BUCKET_BYTES};

use depthsense_infer::NetError;

/// Options of data-parallel training.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DistOptions {
    /// SyncBatchNorm: batch statistics over the global batch.
    pub sync_bn: bool,
    /// Gradient bucket size in bytes (DDP: 25 MB).
    pub bucket_bytes: usize,
    /// After every step, compare every parameter with rank 0's, and with `sync_bn` every
    /// BatchNorm statistic too (bitwise; one broadcast of the model per step — a check for
    /// tests and debugging). Without `sync_bn` the statistics differ after each forward, as
    /// under DDP, until rank 0's are broadcast before the next one.
    pub check_replicas: bool,
}

impl Default for DistOptions {
    fn default() -> Self {
        Self {
            sync_bn: false,
            bucket_bytes: DEFAULT_BUCKET_BYTES,
            check_replicas: false,
        }
    }
}

/// Communication time of a run on this rank.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
pub struct CommStats {
    /// Steps whose gradients were all-reduced.
    pub steps: u64,
    /// Seconds in the gradient all-reduce (flatten, all-reduce, copy back).
    pub grad_allreduce_s: f64,
    /// Bytes all-reduced per step and the number of buckets.
    pub grad_bytes: usize,
    pub buckets: usize,
}

struct SyncBnHook {
    pg: Arc<ProcessGroup>,
    error: RefCell<Option<depthsense_dist::DistError>>,
}

impl BatchNormHook for SyncBnHook {
    fn batch_norm(&self, x: &Tensor, bn: &nn::BatchNorm, momentum: f64, eps: f64) -> Tensor {
        if self.error.borrow().is_none() {
            let state = BnState {
                weight: bn.ws.as_ref(),
                bias: bn.bs.as_ref(),
                running_mean: &bn.running_mean,
                running_var: &bn.running_var,
                momentum,
                eps,
            };
            match batch_norm(&self.pg, x, &state) {
                Ok(y) => return y,
                Err(e) => *self.error.borrow_mut() = Some(e),
            }
        }
        // After a failure: local statistics; the trainer reports the error after the forward.
        bn.forward_t(x, true)
    }
}

/// This process's part in a data-parallel job.
pub struct Dist {
    pg: Arc<ProcessGroup>,
    pub opts: DistOptions,
    grads: Option<GradBuckets>,
    /// Every variable sorted by name, the trainable ones, and the non-trainable floating-point
    /// ones (BatchNorm statistics).
    vars: Vec<Tensor>,
    params: Vec<Tensor>,
    buffers: Vec<Tensor>,
    hook: Option<Rc<SyncBnHook>>,
    /// The head's per-sample dropout seeds, set before every training forward.
    seeds: Rc<DropoutSeeds>,
    pub stats: CommStats,
}

impl Dist {
    pub fn new(pg: ProcessGroup, opts: DistOptions) -> Self {
        Self {
            pg: Arc::new(pg),
            opts,
            grads: None,
            vars: vec![],
            params: vec![],
            buffers: vec![],
            hook: None,
            seeds: Rc::new(DropoutSeeds::default()),
            stats: CommStats::default(),
        }
    }

    /// Join the job the environment describes (torchrun / Slurm / `--nproc`), with NCCL for a
    /// CUDA `device` when compiled in and Gloo otherwise. `Ok(None)`: no distributed
    /// environment (a plain single-process run).
    pub fn from_env(
        opts: DistOptions,
        device: Device,
        timeout: Duration,
    ) -> Result<Option<Self>, NetError> {
        let Some(env) = DistEnv::from_env()? else {
            return Ok(None);
        };
        let index = match device {
            Device::Cuda(i) => Some(i),
            _ => None,
        };
        let pg = ProcessGroup::new(&env, Backend::for_device(device), index, timeout)?;
        Ok(Some(Self::new(pg, opts)))
    }

    pub fn rank(&self) -> usize {
        self.pg.rank()
    }
    pub fn world_size(&self) -> usize {
        self.pg.world_size()
    }
    pub fn is_main(&self) -> bool {
        self.pg.is_main()
    }
    pub fn process_group(&self) -> &ProcessGroup {
        &self.pg
    }

    /// What this rank's network is built with (`DepthNet::with_hooks`): SyncBatchNorm when
    /// asked, and the per-sample dropout seeds that [`Dist::before_forward`] sets.
    pub(crate) fn train_hooks(&mut self) -> TrainHooks {
        if self.opts.sync_bn && self.hook.is_none() {
            self.hook = Some(Rc::new(SyncBnHook {
                pg: self.pg.clone(),
                error: RefCell::new(None),
            }));
        }
        TrainHooks {
            batch_norm: self.hook.clone().map(|h| h as Rc<dyn BatchNormHook>),
            dropout_seeds: Some(self.seeds.clone()),
        }
    }

    /// Make the replicas identical (broadcast from rank 0) and prepare the gradient buckets.
    pub(crate) fn attach(&mut self, vs: &VarStore) -> Result<(), NetError> {
        let mut named: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
        named.sort_by(|a, b| a.0.cmp(&b.0));
        self.vars = named.iter().map(|(_, t)| t.shallow_clone()).collect();
        self.buffers = named
            .iter()
            .filter(|(_, t)| !t.requires_grad() && t.is_floating_point())
            .map(|(_, t)| t.shallow_clone())
            .collect();
        let params: Vec<Tensor> = named
            .iter()
            .filter(|(_, t)| t.requires_grad())
            .map(|(_, t)| t.shallow_clone())
            .collect();
        broadcast_flat(&self.pg, &self.vars, 0, self.opts.bucket_bytes)?;
        self.params = params.iter().map(|t| t.shallow_clone()).collect();
        let grads = GradBuckets::new(params, self.opts.bucket_bytes);
        self.stats.grad_bytes = grads.bucket_bytes().iter().sum();
        self.stats.buckets = grads.bucket_bytes().len();
        self.grads = Some(grads);
        Ok(())
    }

    /// Before a training forward of `local_batch` samples at `iteration`: dropout seeds per
    /// sample (from the sample's place in the global batch, not the rank), and without
    /// SyncBatchNorm rank 0's BatchNorm statistics.
    pub(crate) fn before_forward(
        &self,
        seed: u64,
        iteration: u64,
        local_batch: usize,
    ) -> Result<(), NetError> {
        let first = self.rank() * local_batch;
        let seeds = (first..first + local_batch)
            .map(|g| {
                splitmix64(seed ^ splitmix64(iteration + 1) ^ splitmix64(g as u64 ^ 0xd20_5eed))
            })
            .collect();
        self.seeds.set(Some(seeds));
        if !self.opts.sync_bn && !self.buffers.is_empty() {
            broadcast_flat(&self.pg, &self.buffers, 0, self.opts.bucket_bytes)?;
        }
        Ok(())
    }

    /// After a training forward: a SyncBatchNorm failure, if any.
    pub(crate) fn after_forward(&self) -> Result<(), NetError> {
        if let Some(h) = &self.hook {
            if let Some(e) = h.error.borrow_mut().take() {
                return Err(NetError::SyncBatchNorm(e));
            }
        }
        Ok(())
    }

    /// The mean over the ranks of this rank's loss.
    pub(crate) fn mean_loss(&self, loss: f64) -> Result<f64, NetError> {
        let v = self
            .pg
            .all_reduce_f64(&[loss], ReduceOp::Avg, Device::Cpu)?;
        Ok(v[0])
    }

    /// Average the gradients over the ranks (after backward).
    pub(crate) fn sync_grads(&mut self) -> Result<(), NetError> {
        let Some(g) = &self.grads else {
            return Err(NetError::GradientsNotAttached);
        };
        let s = g.all_reduce(&self.pg)?;
        self.stats.steps += 1;
        self.stats.grad_allreduce_s += s.seconds;
        Ok(())
    }

    /// With `check_replicas`: every parameter (and with `sync_bn` every buffer) equals rank
    /// 0's, bit for bit.
    pub(crate) fn check_replicas(&self, iteration: u64) -> Result<(), NetError> {
        if !self.opts.check_replicas {
            return Ok(());
        }
        let checked = if self.opts.sync_bn {
            &self.vars
        } else {
            &self.params
        };
        let (mine, theirs) = tch::no_grad(|| {
            let parts: Vec<Tensor> = checked
                .iter()
                .filter(|t| t.is_floating_point())
                .map(|t| t.to_kind(Kind::Float).reshape([-1]).to_device(Device::Cpu))
                .collect();
            let mine = Tensor::cat(&parts, 0);
            (mine.copy(), mine)
        });
        self.pg.broadcast(std::slice::from_ref(&theirs), 0)?;
        if !mine.equal(&theirs) {
            let d = (&mine - &theirs).abs().max().double_value(&[]);
            return Err(NetError::ReplicasDiffer {
                rank: self.rank(),
                iteration,
                max_abs_diff: d,
            });
        }
        Ok(())
    }

    /// This rank's contiguous shard of `n` items.
    pub fn shard(&self, n: usize) -> std::ops::Range<usize> {
        let (r, w) = (self.rank(), self.world_size());
        r * n / w..(r + 1) * n / w
    }

    /// The report of all ranks' shards from this rank's: counts and weighted metric sums are
    /// all-reduced (exact up to floating-point summation order).
    pub(crate) fn reduce_report(&self, r: &Report) -> Result<Report, NetError> {
        let agg = r.config.aggregate;
        let mut v: Vec<f64> = Vec::with_capacity(r.rows.len() * 10 + 1);
        for row in &r.rows {
            let w = match agg {
                Aggregate::Image => row.n_images as f64,
                Aggregate::Pooled => row.n_pixels as f64,
            };
            let m = &row.metrics;
            let sq = |x: f64| match agg {
                Aggregate::Image => x,
                Aggregate::Pooled => x * x,
            };
            v.extend_from_slice(&[
                row.n_images as f64,
                row.n_pixels as f64,
                m.delta1 * w,
                m.delta2 * w,
                m.delta3 * w,
                m.abs_rel * w,
                m.sq_rel * w,
                sq(m.rmse) * w,
                sq(m.rmse_log) * w,
                m.mae * w,
            ]);
        }
        v.push(r.images_seen as f64);
        let s = self.pg.all_reduce_f64(&v, ReduceOp::Sum, Device::Cpu)?;
        let mut out = r.clone();
        for (i, row) in out.rows.iter_mut().enumerate() {
            let x = &s[i * 10..i * 10 + 10];
            row.n_images = x[0].round() as u64;
            row.n_pixels = x[1].round() as u64;
            let w = match agg {
                Aggregate::Image => x[0],
                Aggregate::Pooled => x[1],
            };
            row.metrics = if w > 0.0 {
                let root = |x: f64| match agg {
                    Aggregate::Image => x,
                    Aggregate::Pooled => x.max(0.0).sqrt(),
                };
                Metrics {
                    delta1: x[2] / w,
                    delta2: x[3] / w,
                    delta3: x[4] / w,
                    abs_rel: x[5] / w,
                    sq_rel: x[6] / w,
                    rmse: root(x[7] / w),
                    rmse_log: root(x[8] / w),
                    mae: x[9] / w,
                }
            } else {
                Metrics::default()
            };
        }
        out.images_seen = s[s.len() - 1].round() as u64;
        Ok(out)
    }

    /// The stop signal any rank received (SIGINT / SIGTERM), so that every rank stops after the
    /// same step: one scalar all-reduce, asked after every step.
    pub fn agree_on_stop(
        &self,
        local: Option<depthsense_base::interrupt::StopSignal>,
    ) -> Result<Option<depthsense_base::interrupt::StopSignal>, NetError> {
        use depthsense_base::interrupt::StopSignal;
        // Per signal, how many ranks received it (SIGTERM before SIGINT when both were).
        let mine = |s: StopSignal| f64::from(u8::from(local == Some(s)));
        let v = [mine(StopSignal::Terminate), mine(StopSignal::Interrupt)];
        let s = self.pg.all_reduce_f64(&v, ReduceOp::Sum, Device::Cpu)?;
        let agreed = if s[0] > 0.0 {
            Some(StopSignal::Terminate)
        } else if s[1] > 0.0 {
            Some(StopSignal::Interrupt)
        } else {
            None
        };
        if let Some(sig) = agreed {
            // A rank that did not receive it stops as if it had.
            depthsense_base::interrupt::request(sig);
        }
        Ok(agreed)
    }

    /// Wait for every rank.
    pub fn barrier(&self) -> Result<(), NetError> {
        Ok(self.pg.barrier()?)
    }
}

/// The CUDA device of a local rank when `device` asks for CUDA ("auto" with CUDA present,
/// "cuda"), else `device` unchanged. An explicit "cuda:N" is kept.
pub fn device_for_local_rank(device: &str, local_rank: usize) -> String {
    match device {
        "cuda" => format!("cuda:{local_rank}"),
        "auto" if tch::Cuda::is_available() => format!("cuda:{local_rank}"),
        d => d.to_string(),
    }
}
