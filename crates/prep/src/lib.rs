//! Training-frame maps from raw nuScenes (SPEC §3–5): lidar GT, radar raw / height-extended
//! inputs, and the `prepare` pipeline with caching.

pub mod layout;
