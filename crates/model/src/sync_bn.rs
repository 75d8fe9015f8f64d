//! A switch for the training-mode BatchNorm of the ResNet encoders: data-parallel training
//! installs a [`BatchNormHook`] (SyncBatchNorm: statistics over every rank's batch) on the
//! training thread; without one (the default) BatchNorm is libtorch's, unchanged.

use std::cell::RefCell;
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
