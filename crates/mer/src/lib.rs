//! depthsense-mer (layer 6, ARCHITECTURE.md) — MER, the multi-channel enhanced radar of RC-PDA (SPEC §5): association labels from
//! `prepare` output ([`labels`]), training of the PDA network ([`train`]), writing the
//! enhanced maps into every prepared sample ([`apply`], with preview pictures) and the
//! coverage / error measurement against the sparse lidar GT ([`report`]).
//!
//! The on-disk format and the loader's side live in [`depthsense_data::mer_maps`] (re-exported
//! here).

pub mod apply;
pub mod labels;
/// `mer report`: torch-free, in depthsense-score (so `depthsense` runs it without libtorch).
pub use depthsense_score::mer_coverage as report;
pub mod train;

pub use depthsense_data::mer_maps::*;
