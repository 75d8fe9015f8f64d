//! depthsense-mer (layer 6, ARCHITECTURE.md) — MER, the multi-channel enhanced radar of RC-PDA (SPEC §5): association labels from
//! `prepare` output ([`labels`]), training of the PDA network ([`train`]), writing the
//! enhanced maps into every prepared sample ([`apply`], with preview pictures).
//!
//! The on-disk format and the loader's side live in `depthsense_dataset::mer_maps`; the
//! coverage report (`mer report`) in `depthsense_score::mer_coverage` (both torch-free).

pub mod apply;
pub mod labels;
pub mod train;
