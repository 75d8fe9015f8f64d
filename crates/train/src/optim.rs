//! The optimiser a training loop drives: SGD with momentum ([`crate::sgd::Sgd`], `train`) and
//! Adam ([`crate::adam::Adam`], `mer train`) both implement [`Optimizer`], whose state can be
//! saved beside a checkpoint for an exact resume ([`crate::optim_state`]).

use std::path::Path;

use depthsense_infer::NetError;

/// One optimiser over a VarStore's trainable variables.
pub trait Optimizer {
    /// Clears every trainable variable's gradient.
    fn zero_grad(&mut self);
    /// One update with learning rate `lr` (variables without a gradient are left alone).
    fn step(&mut self, lr: f64);
    /// Writes the state (safetensors, atomically) with the iteration it belongs to.
    fn save(&self, path: &Path, iteration: u64) -> Result<(), NetError>;
    /// Restores what [`Optimizer::save`] wrote; returns the iteration stored with it.
    fn load(&mut self, path: &Path) -> Result<u64, NetError>;
}
