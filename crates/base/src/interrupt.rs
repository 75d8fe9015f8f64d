//! SIGINT and SIGTERM as a request to stop at the next safe point (docs/guide/reliability.md,
//! "Pre-emption"): a cluster's scheduler (Slurm's `--signal=TERM@120`, a pre-emption, `scancel`)
//! and Ctrl-C ask a training run to stop; the run finishes its current step, checkpoints and
//! exits with the shell's convention for that signal (128 + its number: 130 for SIGINT, 143
//! for SIGTERM). A **second** signal stops the process at once (the default action of the
//! signal, so the exit status still says which signal ended it). The same signal again within
//! [`REPEAT_WINDOW_MS`] of the first is taken as the same request, not a second one: a cluster
//! that signals every process of a job while a launcher passes the signal on to its workers
//! delivers it twice at once.
//!
//! [`install`] puts the handler in place; the long loops ask [`requested`] between steps. The
//! handler only stores the signal's number in an atomic and, the second time, restores the
//! default action and raises the signal again: both async-signal-safe.

use std::sync::atomic::{AtomicI32, AtomicI64, Ordering};

/// The first stop signal received (0: none).
static REQUESTED: AtomicI32 = AtomicI32::new(0);
/// When it was received (CLOCK_MONOTONIC, milliseconds).
static REQUESTED_AT_MS: AtomicI64 = AtomicI64::new(0);
/// The same signal again within this many milliseconds is the same request.
pub const REPEAT_WINDOW_MS: i64 = 1000;

/// CLOCK_MONOTONIC in milliseconds (async-signal-safe).
fn monotonic_ms() -> i64 {
    // SAFETY: clock_gettime(2) is async-signal-safe and writes only `ts`.
    unsafe {
        let mut ts: libc::timespec = std::mem::zeroed();
        libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts);
        ts.tv_sec as i64 * 1000 + ts.tv_nsec as i64 / 1_000_000
    }
}

/// A signal that asks the process to stop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopSignal {
    /// SIGINT (Ctrl-C on a terminal).
    Interrupt,
    /// SIGTERM (`kill`, Slurm before a pre-emption or at the end of the time limit).
    Terminate,
}

impl StopSignal {
    /// The signal's number.
    pub fn number(self) -> i32 {
        match self {
            StopSignal::Interrupt => libc::SIGINT,
            StopSignal::Terminate => libc::SIGTERM,
        }
    }

    /// The signal of number `n`, when it is one of the two.
    pub fn from_number(n: i32) -> Option<Self> {
        match n {
            libc::SIGINT => Some(StopSignal::Interrupt),
            libc::SIGTERM => Some(StopSignal::Terminate),
            _ => None,
        }
    }

    /// The exit status a shell reports for a process this signal ended: 128 + its number.
    pub fn exit_code(self) -> u8 {
        // 130 and 143: both fit in a u8.
        (128 + self.number()) as u8
    }

    /// Its usual name.
    pub fn name(self) -> &'static str {
        match self {
            StopSignal::Interrupt => "SIGINT",
            StopSignal::Terminate => "SIGTERM",
        }
    }
}

extern "C" fn on_signal(sig: libc::c_int) {
    let now = monotonic_ms();
    if REQUESTED
        .compare_exchange(0, sig, Ordering::SeqCst, Ordering::SeqCst)
        .is_ok()
    {
        REQUESTED_AT_MS.store(now, Ordering::SeqCst);
        return;
    }
    let repeat = REQUESTED.load(Ordering::SeqCst) == sig
        && now - REQUESTED_AT_MS.load(Ordering::SeqCst) < REPEAT_WINDOW_MS;
    if !repeat {
        // The second signal: the default action, now.
        // SAFETY: signal(2) and raise(3) are async-signal-safe.
        unsafe {
            libc::signal(sig, libc::SIG_DFL);
            libc::raise(sig);
        }
    }
}

/// Installs the handler of SIGINT and SIGTERM for this process (every thread). Call it once
/// the command is about to do long work; before that the signals keep their default action.
pub fn install() -> std::io::Result<()> {
    for sig in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: a zeroed sigaction is valid; the handler is async-signal-safe (above).
        unsafe {
            let mut action: libc::sigaction = std::mem::zeroed();
            action.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
            // Restart interrupted system calls: reads and writes in flight finish normally.
            action.sa_flags = libc::SA_RESTART;
            libc::sigemptyset(&mut action.sa_mask);
            if libc::sigaction(sig, &action, std::ptr::null_mut()) != 0 {
                return Err(std::io::Error::last_os_error());
            }
        }
    }
    Ok(())
}

/// The stop signal received so far, if any.
pub fn requested() -> Option<StopSignal> {
    StopSignal::from_number(REQUESTED.load(Ordering::SeqCst))
}

/// Records `signal` as if it had been received (the data-parallel ranks agree on a stop that
/// only some of them received; tests).
pub fn request(signal: StopSignal) {
    if REQUESTED
        .compare_exchange(0, signal.number(), Ordering::SeqCst, Ordering::SeqCst)
        .is_ok()
    {
        REQUESTED_AT_MS.store(monotonic_ms(), Ordering::SeqCst);
    }
}

/// The command line of this process as a shell would take it back (each word quoted where it
/// needs to be), without the words `drop` says to leave out (a flag, and its value when
/// `takes_value`), and with `append` added: the line `continue with: …` prints.
pub fn command_line(args: &[String], drop: &[(&str, bool)], append: &[&str]) -> String {
    let mut out: Vec<String> = vec![];
    let mut it = args.iter();
    'words: while let Some(a) = it.next() {
        for (flag, takes_value) in drop {
            if a == flag {
                if *takes_value {
                    it.next();
                }
                continue 'words;
            }
            if *takes_value && a.starts_with(&format!("{flag}=")) {
                continue 'words;
            }
        }
        out.push(a.clone());
    }
    for a in append {
        if !out.iter().any(|w| w == a) {
            out.push((*a).to_string());
        }
    }
    out.iter()
        .map(|w| shell_word(w))
        .collect::<Vec<_>>()
        .join(" ")
}

/// `w` quoted for a POSIX shell when it holds anything but safe characters.
pub fn shell_word(w: &str) -> String {
    let safe = !w.is_empty()
        && w.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=:,+@%".contains(c));
    if safe {
        w.to_string()
    } else {
        format!("'{}'", w.replace('\'', r"'\''"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exit_codes_follow_the_shell_convention() {
        assert_eq!(StopSignal::Interrupt.exit_code(), 130);
        assert_eq!(StopSignal::Terminate.exit_code(), 143);
        assert_eq!(
            StopSignal::from_number(libc::SIGTERM),
            Some(StopSignal::Terminate)
        );
        assert_eq!(StopSignal::from_number(libc::SIGHUP), None);
    }

    #[test]
    fn the_command_line_to_continue_is_the_same_with_resume() {
        let args: Vec<String> = [
            "depthsense",
            "train",
            "--data",
            "my data",
            "--force",
            "--out=r",
        ]
        .map(String::from)
        .to_vec();
        assert_eq!(
            command_line(&args, &[("--force", false)], &["--resume"]),
            "depthsense train --data 'my data' --out=r --resume"
        );
        let resumed: Vec<String> = ["depthsense", "train", "--resume", "--stop-after", "8"]
            .map(String::from)
            .to_vec();
        assert_eq!(
            command_line(&resumed, &[("--stop-after", true)], &["--resume"]),
            "depthsense train --resume"
        );
        assert_eq!(shell_word("it's"), r"'it'\''s'");
    }

    /// In a child process (this test binary run again): a first SIGTERM is recorded, the same
    /// signal at once again is the same request, a second one later ends the process by the
    /// signal's default action.
    #[test]
    fn a_second_signal_stops_at_once() {
        const CHILD: &str = "DEPTHSENSE_INTERRUPT_TEST_CHILD";
        if std::env::var_os(CHILD).is_some() {
            install().unwrap();
            // SAFETY: raising handled signals in this (child) process.
            unsafe { libc::raise(libc::SIGTERM) };
            unsafe { libc::raise(libc::SIGTERM) };
            assert_eq!(requested(), Some(StopSignal::Terminate));
            std::thread::sleep(std::time::Duration::from_millis(
                REPEAT_WINDOW_MS as u64 + 100,
            ));
            unsafe { libc::raise(libc::SIGTERM) };
            std::thread::sleep(std::time::Duration::from_secs(5));
            std::process::exit(0);
        }
        let exe = std::env::current_exe().unwrap();
        let out = std::process::Command::new(exe)
            .args(["--exact", "interrupt::tests::a_second_signal_stops_at_once"])
            .args(["--nocapture", "--test-threads", "1"])
            .env(CHILD, "1")
            .output()
            .unwrap();
        use std::os::unix::process::ExitStatusExt;
        assert_eq!(
            out.status.signal(),
            Some(libc::SIGTERM),
            "{:?} {}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        );
    }

    #[test]
    fn a_signal_is_recorded_once_and_the_first_one_counts() {
        // The handler itself: a process-wide state, so one test only sets it.
        install().unwrap();
        assert_eq!(requested(), None);
        // SAFETY: raising a handled signal in this process.
        unsafe { libc::raise(libc::SIGTERM) };
        assert_eq!(requested(), Some(StopSignal::Terminate));
        // The same signal at once again (a launcher passing on what the cluster also sent):
        // the same request, the process lives on.
        // SAFETY: as above.
        unsafe { libc::raise(libc::SIGTERM) };
        assert_eq!(requested(), Some(StopSignal::Terminate));
        request(StopSignal::Interrupt);
        assert_eq!(
            requested(),
            Some(StopSignal::Terminate),
            "the first one counts"
        );
    }
}
