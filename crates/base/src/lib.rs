//! The workspace's base layer: what several layers share and no layer owns — the one atomic
//! write (`fsutil`), the one FNV-1a and SplitMix64 (`hash`), folder locks (`lock`), the stop signals
//! (`interrupt`: SIGINT / SIGTERM as a request to checkpoint and stop) and the
//! closed vocabularies of enum words (`words`). No
//! libtorch, no nuScenes; every other crate may use it.

pub mod fsutil;
pub mod hash;
pub mod interrupt;
pub mod lock;
pub mod words;
