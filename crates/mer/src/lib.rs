//! depthsense-mer (layer 6, ARCHITECTURE.md) — MER, the multi-channel enhanced radar of RC-PDA
//! (SPEC §5), its inference side: association labels from `prepare` output ([`labels`]) and
//! writing the enhanced maps into every prepared sample ([`apply`], with preview pictures).
//! Without training code, so that `predict` (its own MER) does not depend on training: the
//! PDA network's training is `depthsense-mer-train`.
//!
//! The on-disk format and the loader's side live in `depthsense_dataset::mer_maps`; the
//! coverage report (`mer report`) in `depthsense_score::mer_coverage` (both torch-free).

pub mod apply;
pub mod labels;
