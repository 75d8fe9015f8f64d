//! depthsense-viz (layer 0, ARCHITECTURE.md): pictures, no tensors — training curves, bar and
//! line charts, depth colour maps with radar overlays and error maps, picture rows with a colour
//! bar in metres ([`plot`]). Tables as text live in `depthsense_metrics::table`.

pub mod plot;

/// A picture could not be drawn or encoded; the message says which and why.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct VizError(pub String);
