//! depthsense-infer (layer 5, ARCHITECTURE.md): a network over prepared samples, beneath both
//! training and evaluation — what `train`'s validation, `eval`, `predict`, `explain`, `mer
//! apply` and the experiments share, so that inference never depends on training.
//!
//! - [`upload`]: a batch onto the device (pinned host memory on CUDA);
//! - [`run`]: a network over samples into the metrics through the one scorer
//!   (`evaluate_net`, `validate_net`), or into per-batch predictions (`run_net`);
//! - [`NetError`]: the one error of the network commands (`depthsense-net`: train, eval,
//!   predict, explain, MER, export, the experiments), defined here, the lowest crate that
//!   reports it, so every message stays the same whichever command raises it.

mod error;
pub mod run;
pub mod upload;

pub use error::NetError;
