//! depthsense-viz (layer 1, ARCHITECTURE.md): pictures, no tensors — training curves, bar and
//! line charts, depth colour maps with radar overlays and error maps, picture rows with a colour
//! bar in metres ([`plot`]). Tables as text live in `depthsense_metrics::table`.

pub mod plot;

/// A picture could not be drawn or encoded.
#[derive(Debug, thiserror::Error)]
pub enum VizError {
    /// plotters failed to draw (its error as it formats itself).
    #[error("plotting failed: {0}")]
    Plot(String),
    /// The PNG encoder failed.
    #[error("PNG encoding failed: {0}")]
    Png(#[source] image::ImageError),
    /// A pixel buffer did not have its picture's size (a bug here, not a bad input).
    #[error("{0} buffer has the wrong size")]
    BufferSize(&'static str),
    /// A picture row was asked for with no panels.
    #[error("picture row: no panels")]
    NoPanels,
}
