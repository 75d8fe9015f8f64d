//! The workspace's base layer: what several layers share and no layer owns — the one atomic
//! write (`fsutil`), the one FNV-1a and SplitMix64 (`hash`) and folder locks (`lock`). No
//! libtorch, no nuScenes; every other crate may use it.

pub mod fsutil;
pub mod hash;
pub mod lock;
