//! SyncBatchNorm: batch statistics over the global batch of every rank.
//!
//! tch cannot define custom autograd functions in Rust, so the one non-standard operation —
//! the cross-rank sum — is a C++ `torch::autograd::Function` in the shim
//! ([`ProcessGroup::all_reduce_sum_autograd`]): forward Σ_ranks x, backward Σ_ranks ∂L/∂y.
//! Everything else is ordinary differentiable tensor algebra, so autograd derives the exact
//! SyncBatchNorm backward (the same as PyTorch's `SyncBatchNorm` under DDP):
//!
//! ```text
//! n  = Σ_ranks count,  μ = Σ_ranks Σ x / n                    (all-reduce 1: [Σx, count])
//! σ² = Σ_ranks Σ (x − μ)² / n                                 (all-reduce 2, two-pass: no
//! y  = (x − μ) / √(σ² + ε) · γ + β                              cancellation of E[x²] − μ²)
//! running_mean ← (1 − m)·running_mean + m·μ,  running_var ← (1 − m)·running_var + m·σ²·n/(n−1)
//! ```
//!
//! With the gradients of the parameters then averaged over the N ranks (DDP), a step on N
//! ranks with per-rank batch B equals a step of one process on the batch N·B whose loss is
//! the mean of the ranks' losses.

use tch::{Kind, Tensor};

use crate::{DistError, ProcessGroup};

/// The tensors of one BatchNorm layer.
pub struct BnState<'a> {
    pub weight: Option<&'a Tensor>,
    pub bias: Option<&'a Tensor>,
    pub running_mean: &'a Tensor,
    pub running_var: &'a Tensor,
    pub momentum: f64,
    pub eps: f64,
}

fn all_reduce_on_comm_device(pg: &ProcessGroup, t: &Tensor) -> Result<Tensor, DistError> {
    let dev = t.device();
    let comm = pg.comm_device(dev);
    let r = pg.all_reduce_sum_autograd(&t.to_device(comm).contiguous())?;
    Ok(r.to_device(dev))
}

/// Training-mode batch norm of `x` ([B, C, …]) with statistics over every rank's batch;
/// updates the running statistics. Differentiable (see the module docs).
pub fn batch_norm(pg: &ProcessGroup, x: &Tensor, bn: &BnState) -> Result<Tensor, DistError> {
    let size = x.size();
    if size.len() < 2 {
        return Err(DistError::BatchNormShape { shape: size });
    }
    let c = size[1];
    let dims: Vec<i64> = (0..size.len() as i64).filter(|&d| d != 1).collect();
    let mut shape = vec![1i64; size.len()];
    shape[1] = c;
    let xf = x.to_kind(Kind::Float);
    let local_n = (x.numel() as i64 / c.max(1)) as f64;
    // 1: Σx and the count in one collective.
    let s = xf.sum_dim_intlist(dims.as_slice(), false, Kind::Float);
    let count = Tensor::from_slice(&[local_n as f32]).to_device(x.device());
    let packed = Tensor::cat(&[s, count], 0);
    let total = all_reduce_on_comm_device(pg, &packed)?;
    let n = total.narrow(0, c, 1).detach();
    let n_value = n.double_value(&[0]);
    let mean = total.narrow(0, 0, c) / &n;
    // 2: Σ(x − μ)².
    let d = &xf - mean.view(shape.as_slice());
    let q = (&d * &d).sum_dim_intlist(dims.as_slice(), false, Kind::Float);
    let var = all_reduce_on_comm_device(pg, &q)? / &n;
    let inv = (&var + bn.eps).rsqrt();
    let mut y = d * inv.view(shape.as_slice());
    if let Some(w) = bn.weight {
        y *= w.to_kind(Kind::Float).view(shape.as_slice());
    }
    if let Some(b) = bn.bias {
        y += b.to_kind(Kind::Float).view(shape.as_slice());
    }
    tch::no_grad(|| {
        let m = bn.momentum;
        let unbiased = if n_value > 1.0 {
            var.detach() * (n_value / (n_value - 1.0))
        } else {
            var.detach()
        };
        let mut rm = bn.running_mean.shallow_clone();
        let mut rv = bn.running_var.shallow_clone();
        let new_rm = &rm * (1.0 - m) + mean.detach().to_kind(rm.kind()) * m;
        let new_rv = &rv * (1.0 - m) + unbiased.to_kind(rv.kind()) * m;
        rm.copy_(&new_rm);
        rv.copy_(&new_rv);
    });
    Ok(y.to_kind(x.kind()))
}
