//! The experiments crate's one integration-test binary (each test binary links libtorch, and
//! linking dominates the test build; issue 35). End-to-end tests live here, the lowest crate
//! that sees training, evaluation and MER together:
//! - `workflow`: loader, training (resume, non-finite loss, config mismatch), evaluation and
//!   prediction on a small generated prepared dataset;
//! - `mer`: MER train → apply → predict's own MER;
//! - `ablation`, `reduced_data`, `data_scale`, `perturb`, `predictions`, `demo_quick`: the
//!   experiments on toy data; `report`: the report page (and in headless Chromium).

mod ablation;
mod common;
mod data_scale;
mod demo_quick;
mod mer;
mod perturb;
mod predictions;
mod reduced_data;
mod report;
mod workflow;

/// libtorch's generator and thread settings are process-wide: `train` seeds the generator and
/// then draws the initial weights and the dropout masks, so two tests training at once in this
/// binary would interleave their draws and a run would not be reproducible. Every test that
/// runs the network holds this lock (of the report page's, the demo page's).
pub fn torch_lock() -> std::sync::MutexGuard<'static, ()> {
    static TORCH: std::sync::Mutex<()> = std::sync::Mutex::new(());
    TORCH.lock().unwrap_or_else(|e| e.into_inner())
}
