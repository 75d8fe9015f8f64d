//! nuScenes tables, indexes, sensor file readers, calibration/pose geometry and projection
//! (SPEC §2). No torch here: this crate builds and tests in seconds.

pub mod depth_png;
pub mod error;
pub mod geometry;
pub mod pcd;
pub mod tables;

pub use error::{NuError, Result};
pub use tables::{NuScenes, Token};
