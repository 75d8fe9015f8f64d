//! Data-parallel training on PyTorch's own distributed engine (c10d), through a small C++ shim
//! (`shim/dist.cpp`) built against the libtorch that tch links:
//!
//! - rendezvous on c10d's `TCPStore` (rank 0 hosts it at `MASTER_ADDR:MASTER_PORT`);
//! - `ProcessGroupGloo` on CPU, `ProcessGroupNCCL` on CUDA (feature `nccl`);
//! - all-reduce (sum / average), broadcast and barrier on tch tensors, with a timeout;
//! - an autograd-aware all-reduce (sum forward, sum of the gradients backward), the
//!   primitive behind [`sync_bn::batch_norm`];
//! - [`GradBuckets`]: DDP's gradient averaging in ≈25 MB flat buckets.
//!
//! A failed or timed-out collective names the peer that stopped: every rank beats a counter
//! in the store every 250 ms, and on failure the survivors look for counters that stopped.
//!
//! [`DistEnv`] reads the environment `torchrun`, Slurm and Kubernetes PyTorchJob set;
//! [`launch`] starts local workers as `torchrun --nproc-per-node` does.

use std::ffi::{c_char, c_int, c_void, CStr, CString};
use std::ptr::NonNull;
use std::time::Duration;

use tch::{Device, Kind, Tensor};

mod env;
pub mod launch;
pub mod sync_bn;

pub use env::{first_host, DistEnv, DEFAULT_PORT};

/// What went wrong, naming the variable, the peer or the operation.
#[derive(Debug, thiserror::Error)]
pub enum DistError {
    #[error("distributed environment: {var}: {reason}")]
    Env { var: String, reason: String },
    #[error("{0}")]
    Rendezvous(String),
    #[error("{0}")]
    Collective(String),
    /// `Backend::Nccl` asked of a build without the feature `nccl`.
    #[error("distributed: the NCCL backend is not compiled in: build with `--features nccl`")]
    NcclNotBuilt,
    /// A name handed to the C++ shim (a host, the store's key prefix) holds a NUL byte.
    #[error("distributed: {what} {value:?} contains a NUL byte")]
    NulByte { what: &'static str, value: String },
    /// The result of a collective cannot be copied back to the host.
    #[error("distributed: reading a reduced tensor back: {0}")]
    ReadBack(#[source] tch::TchError),
    /// SyncBatchNorm given an input without a channel dimension.
    #[error("distributed: sync batch norm needs [B, C, …] input, got {shape:?}")]
    BatchNormShape { shape: Vec<i64> },
    /// A local job (`--nproc`): the launcher or its workers.
    #[error(transparent)]
    Launch(#[from] launch::LaunchError),
}

mod ffi {
    use super::*;
    extern "C" {
        pub fn dsd_last_error() -> *const c_char;
        pub fn dsd_has_nccl() -> c_int;
        pub fn dsd_init(
            host: *const c_char,
            port: c_int,
            rank: c_int,
            world: c_int,
            timeout_ms: i64,
            backend: c_int,
            device: c_int,
            is_server: c_int,
            ns: *const c_char,
        ) -> *mut c_void;
        pub fn dsd_free(pg: *mut c_void);
        pub fn dsd_store_host(host: *const c_char, port: c_int, timeout_ms: i64) -> *mut c_void;
        pub fn dsd_store_free(store: *mut c_void);
        pub fn dsd_backend_name(pg: *mut c_void) -> *const c_char;
        pub fn dsd_allreduce(pg: *mut c_void, ts: *mut *mut c_void, n: c_int, avg: c_int) -> c_int;
        pub fn dsd_broadcast(pg: *mut c_void, ts: *mut *mut c_void, n: c_int, root: c_int)
            -> c_int;
        pub fn dsd_barrier(pg: *mut c_void) -> c_int;
        pub fn dsd_allreduce_autograd(pg: *mut c_void, t: *mut c_void) -> *mut c_void;
    }
}

fn last_error() -> String {
    // SAFETY: the shim returns a pointer to a thread-local NUL-terminated string.
    unsafe { CStr::from_ptr(ffi::dsd_last_error()) }
        .to_string_lossy()
        .into_owned()
}

/// Whether this build has the NCCL backend (feature `nccl`).
pub fn has_nccl() -> bool {
    // SAFETY: no arguments, no state.
    unsafe { ffi::dsd_has_nccl() != 0 }
}

/// Communication backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    /// CPU tensors (and CUDA tensors through host copies); every build.
    Gloo,
    /// CUDA tensors; builds with feature `nccl`.
    Nccl,
}

impl Backend {
    /// NCCL for CUDA devices when compiled in, else Gloo.
    pub fn for_device(device: Device) -> Backend {
        if device.is_cuda() && has_nccl() {
            Backend::Nccl
        } else {
            Backend::Gloo
        }
    }
}

/// Reduction of [`ProcessGroup::all_reduce`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReduceOp {
    Sum,
    /// Sum divided by the world size.
    Avg,
}

/// Default timeout of rendezvous and collectives (`--dist-timeout`).
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(300);

/// One process's membership of the job: a c10d process group.
pub struct ProcessGroup {
    raw: NonNull<c_void>,
    env: DistEnv,
    backend: Backend,
    timeout: Duration,
}

// SAFETY: c10d process groups and TCPStore are used from several threads by libtorch itself
// (work threads, the autograd engine); the shim's group is immutable after creation.
unsafe impl Send for ProcessGroup {}
unsafe impl Sync for ProcessGroup {}

impl std::fmt::Debug for ProcessGroup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProcessGroup")
            .field("rank", &self.env.rank)
            .field("world_size", &self.env.world_size)
            .field("backend", &self.backend)
            .finish()
    }
}

fn ptrs(tensors: &[Tensor]) -> Vec<*mut c_void> {
    tensors.iter().map(|t| t.as_ptr() as *mut c_void).collect()
}

impl ProcessGroup {
    /// Join the job described by `env`: rendezvous (rank 0 hosts the TCPStore), wait until
    /// every rank joined, then connect the backend. `device_index` is the CUDA device of this
    /// rank (NCCL) or ignored (Gloo).
    pub fn new(
        env: &DistEnv,
        backend: Backend,
        device_index: Option<usize>,
        timeout: Duration,
    ) -> Result<Self, DistError> {
        if backend == Backend::Nccl && !has_nccl() {
            return Err(DistError::NcclNotBuilt);
        }
        let host = CString::new(env.master_addr.clone()).map_err(|_| DistError::Env {
            var: "MASTER_ADDR".into(),
            reason: "contains a NUL byte".into(),
        })?;
        let ms = timeout.as_millis().clamp(1, i64::MAX as u128) as i64;
        // Under torchrun (TORCHELASTIC_USE_AGENT_STORE=True) its agent already hosts the store at
        // MASTER_ADDR:MASTER_PORT and outlives worker restarts: every rank is a client, and the
        // keys carry the restart count.
        let is_server = env.rank == 0 && !env.agent_store;
        let ns = format!("depthsense/{}/", env.restart_count);
        let ns = CString::new(ns.clone()).map_err(|_| DistError::NulByte {
            what: "store key prefix",
            value: ns,
        })?;
        // SAFETY: valid C strings; the shim copies them.
        let raw = unsafe {
            ffi::dsd_init(
                host.as_ptr(),
                env.master_port as c_int,
                env.rank as c_int,
                env.world_size as c_int,
                ms,
                match backend {
                    Backend::Gloo => 0,
                    Backend::Nccl => 1,
                },
                device_index.map_or(-1, |d| d as c_int),
                is_server as c_int,
                ns.as_ptr(),
            )
        };
        let raw = NonNull::new(raw).ok_or_else(|| DistError::Rendezvous(last_error()))?;
        Ok(Self {
            raw,
            env: env.clone(),
            backend,
            timeout,
        })
    }

    /// [`ProcessGroup::new`] from [`DistEnv::from_env`]; an error when the environment
    /// describes no distributed job.
    pub fn from_env(
        backend: Backend,
        device_index: Option<usize>,
        timeout: Duration,
    ) -> Result<Self, DistError> {
        let env = DistEnv::from_env()?.ok_or_else(|| DistError::Env {
            var: "WORLD_SIZE".into(),
            reason: "not set (nor SLURM_NTASKS): not launched by torchrun, srun or --nproc".into(),
        })?;
        Self::new(&env, backend, device_index, timeout)
    }

    pub fn rank(&self) -> usize {
        self.env.rank
    }
    pub fn world_size(&self) -> usize {
        self.env.world_size
    }
    pub fn local_rank(&self) -> usize {
        self.env.local_rank
    }
    pub fn is_main(&self) -> bool {
        self.env.rank == 0
    }
    pub fn env(&self) -> &DistEnv {
        &self.env
    }
    pub fn backend(&self) -> Backend {
        self.backend
    }
    pub fn timeout(&self) -> Duration {
        self.timeout
    }
    /// "gloo" or "nccl".
    pub fn backend_name(&self) -> String {
        // SAFETY: the group is alive; the name is owned by it.
        unsafe { CStr::from_ptr(ffi::dsd_backend_name(self.raw.as_ptr())) }
            .to_string_lossy()
            .into_owned()
    }

    /// In-place all-reduce of each tensor (one collective per tensor, all in flight at once;
    /// contiguous tensors).
    pub fn all_reduce(&self, tensors: &[Tensor], op: ReduceOp) -> Result<(), DistError> {
        if tensors.is_empty() {
            return Ok(());
        }
        let mut p = ptrs(tensors);
        // SAFETY: the tensors outlive the call; the shim only reads the handles.
        let rc = unsafe {
            ffi::dsd_allreduce(
                self.raw.as_ptr(),
                p.as_mut_ptr(),
                p.len() as c_int,
                (op == ReduceOp::Avg) as c_int,
            )
        };
        if rc != 0 {
            return Err(DistError::Collective(last_error()));
        }
        Ok(())
    }

    /// In-place broadcast of each tensor from `root`.
    pub fn broadcast(&self, tensors: &[Tensor], root: usize) -> Result<(), DistError> {
        if tensors.is_empty() {
            return Ok(());
        }
        let mut p = ptrs(tensors);
        // SAFETY: as in all_reduce.
        let rc = unsafe {
            ffi::dsd_broadcast(
                self.raw.as_ptr(),
                p.as_mut_ptr(),
                p.len() as c_int,
                root as c_int,
            )
        };
        if rc != 0 {
            return Err(DistError::Collective(last_error()));
        }
        Ok(())
    }

    /// Wait until every rank reaches this point.
    pub fn barrier(&self) -> Result<(), DistError> {
        // SAFETY: the group is alive.
        if unsafe { ffi::dsd_barrier(self.raw.as_ptr()) } != 0 {
            return Err(DistError::Collective(last_error()));
        }
        Ok(())
    }

    /// Σ over ranks of `t`, as a new tensor that stays in the autograd graph: its backward
    /// all-reduces (sums) the incoming gradient, so rank r's `t` receives Σ_ranks ∂L_rank/∂y.
    /// A collective failure during backward surfaces as `f_backward`'s error.
    pub fn all_reduce_sum_autograd(&self, t: &Tensor) -> Result<Tensor, DistError> {
        // SAFETY: `t` outlives the call; the shim returns a new owned tensor handle, which
        // tch takes over (freed by Tensor's Drop).
        let out =
            unsafe { ffi::dsd_allreduce_autograd(self.raw.as_ptr(), t.as_ptr() as *mut c_void) };
        if out.is_null() {
            return Err(DistError::Collective(last_error()));
        }
        // SAFETY: `out` is a heap `at::Tensor*` as tch's own handles are.
        Ok(unsafe { Tensor::from_ptr(out as *mut _) })
    }

    /// Scalar all-reduce of a f64 (e.g. the loss), on the backend's device.
    pub fn all_reduce_f64(
        &self,
        v: &[f64],
        op: ReduceOp,
        device: Device,
    ) -> Result<Vec<f64>, DistError> {
        let t = Tensor::from_slice(v).to_device(self.comm_device(device));
        self.all_reduce(std::slice::from_ref(&t), op)?;
        Vec::<f64>::try_from(t.to_device(Device::Cpu)).map_err(DistError::ReadBack)
    }

    /// The device collectives of this group run on for tensors that live on `device`.
    pub fn comm_device(&self, device: Device) -> Device {
        match self.backend {
            Backend::Nccl => device,
            Backend::Gloo => Device::Cpu,
        }
    }
}

impl Drop for ProcessGroup {
    fn drop(&mut self) {
        // SAFETY: created by dsd_init, freed once.
        unsafe { ffi::dsd_free(self.raw.as_ptr()) }
    }
}

/// A TCPStore server alone, as torchrun's elastic agent hosts one at MASTER_ADDR:MASTER_PORT
/// (`TORCHELASTIC_USE_AGENT_STORE=True`): then every rank, rank 0 included, is a client.
pub struct StoreHost {
    raw: NonNull<c_void>,
}

impl StoreHost {
    pub fn new(host: &str, port: u16, timeout: Duration) -> Result<Self, DistError> {
        let h = CString::new(host).map_err(|_| DistError::NulByte {
            what: "store host",
            value: host.to_string(),
        })?;
        let ms = timeout.as_millis().clamp(1, i64::MAX as u128) as i64;
        // SAFETY: valid C string, copied by the shim.
        let raw = unsafe { ffi::dsd_store_host(h.as_ptr(), port as c_int, ms) };
        let raw = NonNull::new(raw).ok_or_else(|| DistError::Rendezvous(last_error()))?;
        Ok(Self { raw })
    }
}

impl Drop for StoreHost {
    fn drop(&mut self) {
        // SAFETY: created by dsd_store_host, freed once.
        unsafe { ffi::dsd_store_free(self.raw.as_ptr()) }
    }
}

/// Default gradient bucket size: DDP's `bucket_cap_mb = 25`.
pub const DEFAULT_BUCKET_BYTES: usize = 25 * 1024 * 1024;

/// DDP's gradient averaging: the trainable parameters grouped into flat buckets of at most
/// `bucket_bytes` (in reverse registration order, the order in which backward produces
/// gradients), each bucket flattened, all-reduced (average) and copied back.
pub struct GradBuckets {
    /// Parameter indices per bucket.
    buckets: Vec<Vec<usize>>,
    params: Vec<Tensor>,
}

/// Time and volume of one [`GradBuckets::all_reduce`].
#[derive(Debug, Clone, Copy, Default)]
pub struct SyncStats {
    pub buckets: usize,
    pub bytes: usize,
    pub seconds: f64,
}

impl GradBuckets {
    /// `params` in registration order; every one must require grad.
    pub fn new(params: Vec<Tensor>, bucket_bytes: usize) -> Self {
        let mut buckets: Vec<Vec<usize>> = vec![];
        let mut cur: Vec<usize> = vec![];
        let mut cur_bytes = 0usize;
        let mut cur_kind = None;
        for i in (0..params.len()).rev() {
            let p = &params[i];
            let bytes = p.numel() * p.kind().elt_size_in_bytes();
            let kind = (p.kind(), p.device());
            if !cur.is_empty() && (cur_bytes + bytes > bucket_bytes || cur_kind != Some(kind)) {
                buckets.push(std::mem::take(&mut cur));
                cur_bytes = 0;
            }
            cur.push(i);
            cur_bytes += bytes;
            cur_kind = Some(kind);
        }
        if !cur.is_empty() {
            buckets.push(cur);
        }
        Self { buckets, params }
    }

    /// Number of buckets and their sizes in bytes.
    pub fn bucket_bytes(&self) -> Vec<usize> {
        self.buckets
            .iter()
            .map(|b| {
                b.iter()
                    .map(|&i| self.params[i].numel() * self.params[i].kind().elt_size_in_bytes())
                    .sum()
            })
            .collect()
    }

    /// Average every parameter's gradient over the ranks (after backward). A parameter
    /// without a gradient contributes zeros and keeps no gradient.
    pub fn all_reduce(&self, pg: &ProcessGroup) -> Result<SyncStats, DistError> {
        let t0 = std::time::Instant::now();
        let mut stats = SyncStats::default();
        let flats: Vec<Tensor> = tch::no_grad(|| {
            self.buckets
                .iter()
                .map(|b| {
                    let parts: Vec<Tensor> = b
                        .iter()
                        .map(|&i| {
                            let p = &self.params[i];
                            let g = p.grad();
                            if g.defined() {
                                g.reshape([-1])
                            } else {
                                Tensor::zeros([p.numel() as i64], (p.kind(), p.device()))
                            }
                        })
                        .collect();
                    let flat = Tensor::cat(&parts, 0);
                    let dev = pg.comm_device(flat.device());
                    flat.to_device(dev).contiguous()
                })
                .collect()
        });
        for f in &flats {
            stats.bytes += f.numel() * f.kind().elt_size_in_bytes();
        }
        stats.buckets = flats.len();
        pg.all_reduce(&flats, ReduceOp::Avg)?;
        tch::no_grad(|| {
            for (b, flat) in self.buckets.iter().zip(&flats) {
                let mut off = 0i64;
                for &i in b {
                    let p = &self.params[i];
                    let n = p.numel() as i64;
                    let mut g = p.grad();
                    if g.defined() {
                        let src = flat.narrow(0, off, n).to_device(g.device()).view_as(&g);
                        g.copy_(&src);
                    }
                    off += n;
                }
            }
        });
        stats.seconds = t0.elapsed().as_secs_f64();
        Ok(stats)
    }
}

/// Broadcast tensors from `root` in flat buckets (one collective per kind/device group of at
/// most `bucket_bytes`), e.g. parameters and buffers at start.
pub fn broadcast_flat(
    pg: &ProcessGroup,
    tensors: &[Tensor],
    root: usize,
    bucket_bytes: usize,
) -> Result<(), DistError> {
    let mut groups: Vec<Vec<usize>> = vec![];
    let mut cur: Vec<usize> = vec![];
    let mut cur_bytes = 0;
    let mut cur_kind: Option<(Kind, Device)> = None;
    for (i, t) in tensors.iter().enumerate() {
        let bytes = t.numel() * t.kind().elt_size_in_bytes();
        let kind = (t.kind(), t.device());
        if !cur.is_empty() && (cur_bytes + bytes > bucket_bytes || cur_kind != Some(kind)) {
            groups.push(std::mem::take(&mut cur));
            cur_bytes = 0;
        }
        cur.push(i);
        cur_bytes += bytes;
        cur_kind = Some(kind);
    }
    if !cur.is_empty() {
        groups.push(cur);
    }
    let flats: Vec<Tensor> = tch::no_grad(|| {
        groups
            .iter()
            .map(|g| {
                let parts: Vec<Tensor> = g.iter().map(|&i| tensors[i].reshape([-1])).collect();
                let flat = Tensor::cat(&parts, 0);
                flat.to_device(pg.comm_device(flat.device())).contiguous()
            })
            .collect()
    });
    pg.broadcast(&flats, root)?;
    tch::no_grad(|| {
        for (g, flat) in groups.iter().zip(&flats) {
            let mut off = 0i64;
            for &i in g {
                let mut t = tensors[i].shallow_clone();
                let n = t.numel() as i64;
                let src = flat.narrow(0, off, n).to_device(t.device()).view_as(&t);
                t.copy_(&src);
                off += n;
            }
        }
    });
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The typed variants read as the strings they replaced did.
    #[test]
    fn typed_variants_name_what_went_wrong() {
        assert_eq!(
            DistError::NcclNotBuilt.to_string(),
            "distributed: the NCCL backend is not compiled in: build with `--features nccl`"
        );
        assert_eq!(
            DistError::BatchNormShape { shape: vec![4] }.to_string(),
            "distributed: sync batch norm needs [B, C, …] input, got [4]"
        );
        let e = StoreHost::new("local\0host", 1, Duration::from_secs(1))
            .err()
            .map(|e| e.to_string());
        assert_eq!(
            e.as_deref(),
            Some("distributed: store host \"local\\0host\" contains a NUL byte")
        );
    }
}
