//! depthsense-viz (layer 0, ARCHITECTURE.md): pictures and tables, no tensors — training
//! curves, bar and line charts, depth colour maps with radar overlays and error maps, picture
//! rows with a colour bar in metres ([`plot`]); Markdown and CSV tables with one rendering of a
//! missing value per format ([`table`]).

pub mod plot;
pub mod table;

/// A picture could not be drawn or encoded; the message says which and why.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct VizError(pub String);
