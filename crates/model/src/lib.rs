//! The DepthSense network, heads and losses on libtorch (SPEC §6–7).
//!
//! - [`ModelConfig`] with presets `paper`, `released`, `tiny` and per-field options;
//! - [`DepthNet`]: `forward_t` → low-resolution head output, `loss`, `decode`;
//! - [`ordinal`]: the exact and efficient ordinal loss/decoding, [`reference`]: the naive form;
//! - [`checkpoint`]: safetensors + config JSON; [`weights`]: torchvision / released imports;
//! - [`report`]: parameters per module and multiply-adds at 350x800;
//! - [`pda`]: the MER radar–pixel association network (SPEC §5);
//! - [`sync_bn`]: the BatchNorm switch of data-parallel training (SyncBatchNorm).

pub mod checkpoint;
pub mod config;
pub mod device;
mod error;
#[cfg(test)]
mod init_tests;
mod layers;
mod net;
pub mod ordinal;
pub mod pda;
pub mod pickle;
pub mod precision;
pub mod reference;
pub mod report;
pub mod sid;
pub mod sync_bn;
pub mod weights;

pub use config::{
    AttentionGate, DecoderKind, Fusion, HeadKind, ModelConfig, RadarBranchKind, RadarInput,
    SidConfig, StemKind,
};
pub use error::{ModelError, ShapeMismatch};
pub use layers::MacRows;
pub use net::DepthNet;
