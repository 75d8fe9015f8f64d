//! Training-frame maps from raw nuScenes (SPEC §3–5): lidar GT, radar raw / height-extended
//! inputs, and the `prepare` pipeline with caching.

pub mod bench;
pub mod calibration;
pub mod error;
pub mod index;
pub mod inspect;
pub mod layout;
pub mod maps;
pub mod motion;
pub mod pipeline;
pub mod radar_oracle;
pub mod radar_points;
pub mod splits;
pub mod verify;

pub use pipeline::{
    prepare, split_scene_tokens, PrepError, PrepareOptions, PrepareSummary, Shard, ShardFault,
};
