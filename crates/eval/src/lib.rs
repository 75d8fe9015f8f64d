//! depthsense-eval (layer 7, ARCHITECTURE.md): a trained network put to use —
//!
//! - [`evaluate`]: `eval` (SPEC §10 tables 1–3 as Markdown, CSV, JSON; radar drop; scoring
//!   other methods' depth maps with `--predictions`);
//! - [`predict`]: depth for a prepared sample, a dataroot token or raw files (`predict`);
//!   [`predict_frames`]: over a list of tokens, pipelined (loader threads, the network, a
//!   writer thread);
//! - [`explain`]: Grad-CAM++ overlays (`explain`).

pub mod evaluate;
pub mod explain;
pub mod predict;
pub mod predict_frames;
