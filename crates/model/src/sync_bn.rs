//! The switches of data-parallel training, decided when the network is built
//! ([`crate::DepthNet::with_hooks`]; in the manner of candle-nn, a layer is built as what it
//! is, and its forward reads no global state). [`TrainHooks::default`], which
//! [`crate::DepthNet::new`] uses, leaves the network unchanged:
//! - `batch_norm`: a [`BatchNormHook`] replaces the training-mode BatchNorm of the ResNet
//!   encoders (SyncBatchNorm: statistics over every rank's batch);
//! - `dropout_seeds`: [`DropoutSeeds`] make the head's Dropout2d masks a function of a seed per
//!   sample, so a sample is dropped the same way whichever rank, and whichever batch slice, it
//!   lands in. The trainer keeps a handle and sets the seeds before each training forward.

use std::cell::{Cell, RefCell};
use std::rc::Rc;

use depthsense_base::hash::splitmix64;
use tch::{nn, nn::ModuleT, Tensor};

/// PyTorch's BatchNorm defaults, which `layers::batch_norm2d` uses.
pub const BN_MOMENTUM: f64 = 0.1;
pub const BN_EPS: f64 = 1e-5;

/// Replaces the training-mode forward of every encoder BatchNorm layer.
pub trait BatchNormHook {
    /// Normalise `x` ([B, C, H, W]) with `bn`'s affine parameters and update its running
    /// statistics. It cannot fail: a hook that hits an error keeps it for its owner to
    /// collect and falls back to local statistics.
    fn batch_norm(&self, x: &Tensor, bn: &nn::BatchNorm, momentum: f64, eps: f64) -> Tensor;
}

/// The per-sample seeds of the next training forward, shared between the trainer (which sets
/// them) and the head (which draws its Dropout2d masks from them).
#[derive(Debug, Default)]
pub struct DropoutSeeds {
    seeds: RefCell<Option<Vec<u64>>>,
    /// Dropout layers run since the seeds were set.
    call: Cell<u64>,
}

impl DropoutSeeds {
    /// Seeds of the samples of the next training forward, in batch order (`None`: dropout
    /// draws from libtorch's generator, as usual). Restarts the count of dropout layers.
    pub fn set(&self, seeds: Option<Vec<u64>>) {
        *self.seeds.borrow_mut() = seeds;
        self.call.set(0);
    }
}

/// What a network is built with for data-parallel training (see the module docs).
#[derive(Clone, Default)]
pub struct TrainHooks {
    pub batch_norm: Option<Rc<dyn BatchNormHook>>,
    pub dropout_seeds: Option<Rc<DropoutSeeds>>,
}

/// Dropout2d (whole channels, kept ones scaled by 1/(1−p)). With sample seeds set, channel c
/// of sample i in the k-th dropout layer of the forward is kept iff
/// U(mix(seed_i, k, c)) ≥ p; else libtorch's `feature_dropout`.
pub(crate) fn feature_dropout(
    x: &Tensor,
    p: f64,
    train: bool,
    seeds: Option<&DropoutSeeds>,
) -> Tensor {
    if !train || p <= 0.0 {
        return x.feature_dropout(p, train);
    }
    let size = x.size();
    let Some(seeds) = seeds else {
        return x.feature_dropout(p, train);
    };
    let set = seeds.seeds.borrow().clone();
    let Some(samples) = set.filter(|s| size.len() >= 2 && s.len() as i64 == size[0]) else {
        return x.feature_dropout(p, train);
    };
    let k = seeds.call.get();
    seeds.call.set(k + 1);
    let channels = size[1] as u64;
    let scale = if p >= 1.0 { 0.0 } else { 1.0 / (1.0 - p) };
    let mut mask = Vec::with_capacity(samples.len() * channels as usize);
    for &s in &samples {
        for c in 0..channels {
            let r = splitmix64(s ^ splitmix64((k << 32) ^ c ^ 0xd209_u64));
            let u = (r >> 11) as f64 / (1u64 << 53) as f64;
            mask.push(if u >= p { scale as f32 } else { 0.0 });
        }
    }
    let mut shape = vec![1i64; size.len()];
    shape[0] = size[0];
    shape[1] = size[1];
    let mask = Tensor::from_slice(&mask)
        .view(shape.as_slice())
        .to_kind(x.kind())
        .to_device(x.device());
    x * mask
}

/// BatchNorm forward: `hook` in training mode when the layer was built with one, else
/// libtorch's.
pub(crate) fn forward_t(
    bn: &nn::BatchNorm,
    x: &Tensor,
    train: bool,
    hook: Option<&Rc<dyn BatchNormHook>>,
) -> Tensor {
    match hook {
        Some(h) if train => h.batch_norm(x, bn, BN_MOMENTUM, BN_EPS),
        _ => bn.forward_t(x, train),
    }
}
