//! The switches of data-parallel training, per training thread; unset (the default), the
//! network is unchanged:
//! - a [`BatchNormHook`] replaces the training-mode BatchNorm of the ResNet encoders
//!   (SyncBatchNorm: statistics over every rank's batch);
//! - [`set_sample_seeds`] makes the head's Dropout2d masks a function of a seed per sample, so
//!   a sample is dropped the same way whichever rank, and whichever batch slice, it lands in.

use std::cell::{Cell, RefCell};
use std::rc::Rc;

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

thread_local! {
    static HOOK: RefCell<Option<Rc<dyn BatchNormHook>>> = const { RefCell::new(None) };
    static SAMPLE_SEEDS: RefCell<Option<Vec<u64>>> = const { RefCell::new(None) };
    static DROPOUT_CALL: Cell<u64> = const { Cell::new(0) };
}

/// Seeds of the samples of the next training forward, in batch order (`None`: dropout draws
/// from libtorch's generator, as usual). Restarts the count of dropout layers.
pub fn set_sample_seeds(seeds: Option<Vec<u64>>) {
    SAMPLE_SEEDS.with(|s| *s.borrow_mut() = seeds);
    DROPOUT_CALL.with(|c| c.set(0));
}

use depthsense_base::hash::splitmix64;

/// Dropout2d (whole channels, kept ones scaled by 1/(1−p)). With sample seeds set, channel c
/// of sample i in the k-th dropout layer of the forward is kept iff
/// U(mix(seed_i, k, c)) ≥ p; else libtorch's `feature_dropout`.
pub(crate) fn feature_dropout(x: &Tensor, p: f64, train: bool) -> Tensor {
    if !train || p <= 0.0 {
        return x.feature_dropout(p, train);
    }
    let size = x.size();
    let seeds = SAMPLE_SEEDS.with(|s| s.borrow().clone());
    let Some(seeds) = seeds.filter(|s| size.len() >= 2 && s.len() as i64 == size[0]) else {
        return x.feature_dropout(p, train);
    };
    let k = DROPOUT_CALL.with(|c| {
        let k = c.get();
        c.set(k + 1);
        k
    });
    let channels = size[1] as u64;
    let scale = if p >= 1.0 { 0.0 } else { 1.0 / (1.0 - p) };
    let mut mask = Vec::with_capacity(seeds.len() * channels as usize);
    for &s in &seeds {
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

/// Install (`Some`) or remove (`None`) the hook of this thread; returns the previous one.
pub fn set_batch_norm_hook(hook: Option<Rc<dyn BatchNormHook>>) -> Option<Rc<dyn BatchNormHook>> {
    HOOK.with(|h| std::mem::replace(&mut *h.borrow_mut(), hook))
}

/// BatchNorm forward: the hook in training mode when one is installed, else libtorch's.
pub(crate) fn forward_t(bn: &nn::BatchNorm, x: &Tensor, train: bool) -> Tensor {
    if train {
        if let Some(h) = HOOK.with(|h| h.borrow().clone()) {
            return h.batch_norm(x, bn, BN_MOMENTUM, BN_EPS);
        }
    }
    bn.forward_t(x, train)
}
