//! depthsense-dataset (layer 3, ARCHITECTURE.md): a prepared data folder as the torch-free
//! commands and the training stack both read it — the index and its train / validation / test
//! partition ([`index`]), a sample's files ([`maps`]), the MER maps on disk ([`mer_maps`]) and
//! the one rule for output folders ([`outputs`]). No tensors: `depthsense` (the front that
//! never loads libtorch) runs `eval --predictions`, `mer report` and `report` on it;
//! `depthsense-data` builds the loader on top.

pub mod error;
pub mod index;
pub mod maps;
pub mod mer_maps;
pub mod outputs;

pub use error::{DataError, ExclusionFault, SampleFolder};
pub use index::{partition, subsample, Dataset, Partition};
pub use maps::{
    check_sample_dir, check_size, decode_rgb, read_depth, read_lowheight_mask, read_meta,
};
