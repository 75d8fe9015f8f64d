//! depthsense-score (layer 4, ARCHITECTURE.md): scoring depth maps on disk against a prepared
//! folder's ground truth, without tensors — the one scorer ([`score_image`], SPEC §9) every
//! evaluation goes through, other methods' predictions (`eval --predictions`,
//! [`predictions`]), the tables files `eval` writes ([`tables`]) and the radar maps' coverage
//! and error (`mer report`, [`mer_coverage`]). `depthsense` runs these commands without
//! loading libtorch.

pub mod mer_coverage;
pub mod npy;
pub mod predictions;
pub mod scorer;
pub mod tables;

pub use scorer::{condition_names, score_image};
