//! The one progress-bar style of the long commands.

use indicatif::{ProgressBar, ProgressStyle};

/// A bar `PREFIX [=====>    ] pos/len elapsed ETA msg`; the caller sets its length.
pub fn progress_bar(prefix: &str) -> ProgressBar {
    let pb = ProgressBar::new(0);
    pb.set_style(
        ProgressStyle::with_template(
            "{prefix:>6.bold} [{bar:30}] {pos}/{len} {elapsed_precise} ETA {eta} {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    pb.set_prefix(prefix.to_string());
    pb
}
