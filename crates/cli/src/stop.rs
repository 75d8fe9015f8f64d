//! Pre-emption-safe training on the command line (docs/guide/reliability.md, "Pre-emption"):
//! `train` and `mer train` catch SIGINT and SIGTERM ([`catch_stop_signals`]), their loop
//! checkpoints after the current step, and the command ends with one line that says how to
//! continue ([`interrupted`]) and the shell's exit status for that signal (130, 143).

use std::process::ExitCode;

use depthsense_base::interrupt::{self, StopSignal};

/// The environment variable in which `train --nproc N` hands its own command line to its
/// workers (a JSON array of words), so that rank 0 records and prints the command the user
/// typed, `--nproc` included.
pub const INVOCATION_ENV: &str = "DEPTHSENSE_INVOCATION";

/// The words of the command the user typed: this process's arguments (`depthsense …`: the
/// handoff keeps argv[0]), or the launcher's when this process is one of its workers.
pub fn invocation() -> Vec<String> {
    std::env::var(INVOCATION_ENV)
        .ok()
        .and_then(|j| serde_json::from_str::<Vec<String>>(&j).ok())
        .unwrap_or_else(|| std::env::args().collect())
}

/// From here on, SIGINT and SIGTERM ask the training loop to checkpoint and stop; a second one
/// stops at once ([`depthsense_base::interrupt`]).
pub fn catch_stop_signals() -> anyhow::Result<()> {
    interrupt::install()
        .map_err(|e| anyhow::anyhow!("cannot install the SIGINT / SIGTERM handler: {e}"))
}

/// The words that must not come back in the command that continues a run: `--resume` is
/// refused beside `--force` and `--init-from`, and an `--extend` is continued by `--resume`
/// alone (its new schedule is in the checkpoint).
const NOT_IN_RESUME: [(&str, bool); 3] = [
    ("--force", false),
    ("--init-from", true),
    ("--extend", false),
];

/// The line a run stopped by `signal` at `iteration` of `total` ends with.
pub fn interrupted_line(words: &[String], iteration: u64, total: u64) -> String {
    format!(
        "interrupted at iteration {iteration} of {total}; continue with: {}",
        interrupt::command_line(words, &NOT_IN_RESUME, &["--resume"])
    )
}

/// Prints [`interrupted_line`] for this invocation and returns the signal's exit status.
pub fn interrupted(signal: StopSignal, iteration: u64, total: u64) -> ExitCode {
    eprintln!("{}", interrupted_line(&invocation(), iteration, total));
    ExitCode::from(signal.exit_code())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_continue_line_is_the_command_with_resume() {
        let w = |s: &str| s.split(' ').map(String::from).collect::<Vec<_>>();
        assert_eq!(
            interrupted_line(&w("depthsense train --data p --out r --force"), 12, 40),
            "interrupted at iteration 12 of 40; continue with: depthsense train --data p --out r \
             --resume"
        );
        assert_eq!(
            interrupted_line(
                &w("depthsense train --out r --init-from b.safetensors"),
                3,
                8
            ),
            "interrupted at iteration 3 of 8; continue with: depthsense train --out r --resume"
        );
        assert_eq!(
            interrupted_line(&w("depthsense train --out r --resume --extend"), 3, 8),
            "interrupted at iteration 3 of 8; continue with: depthsense train --out r --resume"
        );
    }
}
