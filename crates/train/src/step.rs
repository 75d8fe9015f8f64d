//! The training step, shared by `train` (trainer::session), `bench train` and `bench model`:
//! the precision of a step, the loss of one uploaded batch ([`forward_loss`]) and the update
//! after it ([`backward_update`]) — what `bench model` times is what `train` runs.

use depthsense_config::flags::Precision;
use depthsense_model::precision::with_autocast;
use depthsense_model::DepthNet;
use tch::{Kind, Tensor};

use depthsense_infer::upload::BatchTensors;

use crate::optim::Optimizer;

/// `--amp`: bf16 autocast (CUDA only). Not fp16: fp16 without loss scaling underflows the
/// ≈1e-6 per-pixel gradients of the ordinal loss; bf16 has fp32's exponent range.
pub const AMP_PRECISION: Precision = Precision::Bf16;

/// The precision of a step: [`AMP_PRECISION`] with `--amp`, else fp32.
pub fn step_precision(amp: bool) -> Precision {
    if amp {
        AMP_PRECISION
    } else {
        Precision::Fp32
    }
}

/// Forward in training mode under `precision`, then the loss in fp32 on the batch's sparse
/// target: a scalar tensor on the device (not read back, so the step needs no sync).
pub fn forward_loss(net: &DepthNet, bt: &BatchTensors, precision: Precision) -> Tensor {
    let out = with_autocast(precision, || net.forward_t(&bt.image, &bt.radar, true));
    net.loss_sparse(&out.to_kind(Kind::Float), &bt.target_m, &bt.sparse)
}

/// The second half of a single-process step: gradients of `loss` and the optimiser's update
/// at `lr` (a data-parallel step adds its gradient all-reduce between the two).
pub fn backward_update(optim: &mut dyn Optimizer, loss: &Tensor, lr: f64) {
    optim.zero_grad();
    loss.backward();
    optim.step(lr);
}
