//! The one progress of the long commands: a bar on a terminal, plain lines in a log file
//! (`depthsense_progress`).

use depthsense_progress::Progress;

/// A progress named `prefix` (bar on a terminal, lines otherwise); the caller sets its length.
pub fn progress_bar(prefix: &str) -> Progress {
    Progress::new(prefix)
}
