//! The DepthSense network, heads and losses on libtorch (SPEC §6–7).
//!
//! - the network is built from a `depthsense_config::ModelConfig` (torch-free: presets,
//!   per-field options); reading and writing weights is `depthsense-checkpoint`'s (no file
//!   I/O here);
//! - [`DepthNet`] (`net`): `forward_t` → low-resolution head output, `loss`, `decode`,
//!   assembled from the paper's boxes (SPEC §6), one module each (crate-private):
//!   `encoder` (the ResNet RGB encoder, VarStore `rgb.`, and the radar branch's backbone),
//!   `decoder` (the image decoder over C2..C4, `decoder.`), `radar_branch` (the radar branch
//!   of late fusion, `radar.`, the high-resolution radar path, `radar_skip.`, and nearest-depth
//!   pooling), `fusion` (early / late fusion and the CBAM spatial attention, `attention.`) and
//!   `head` (the head convs, `head.`); `layers` holds their building blocks (conv, conv + BN,
//!   initialisation, multiply-add counting);
//! - [`ordinal`]: the exact and efficient ordinal loss/decoding, [`reference`]: the naive form;
//! - [`report`]: parameters per module and multiply-adds at 350x800;
//! - [`pda`]: the MER radar–pixel association network (SPEC §5);
//! - [`sync_bn`]: what data-parallel training builds a network with (`TrainHooks`:
//!   SyncBatchNorm, per-sample dropout seeds), given at construction.

mod decoder;
pub mod device;
mod encoder;
mod error;
pub mod fused_decode;
mod fusion;
pub mod graphed;
mod head;
#[cfg(test)]
mod inference_tests;
#[cfg(test)]
mod init_tests;
mod layers;
mod net;
pub mod ordinal;
pub mod pda;
pub mod precision;
mod radar_branch;
pub mod reference;
pub mod report;
pub mod sid;
pub mod sync_bn;
#[cfg(test)]
mod test_rng;

pub use error::{ModelError, ShapeMismatch};
pub use layers::MacRows;
pub use net::DepthNet;
