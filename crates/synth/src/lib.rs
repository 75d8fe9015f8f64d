//! The synthetic nuScenes-format world (the embedded default dataset).
