//! One writer per output folder: an advisory `flock(2)` on `FOLDER/.depthsense.lock`, held for
//! as long as the command writes there. The kernel releases it when the process ends in any
//! way (SIGKILL included), so a killed run never leaves a stale lock; the file itself stays and
//! only says who held it last. A second process fails at once, naming the holder
//! (docs/guide/reliability.md).
//!
//! - [`OutputLock::exclusive`]: `train`, `mer train`, `mer apply`, `experiment *`, `index
//!   merge`, `demo` — nobody else may write the folder;
//! - [`OutputLock::shared`]: `prepare`, of which several processes (shards) may share one
//!   `--out` by design, but never with an exclusive writer;
//! - [`OutputLock::wait_exclusive`]: a short critical section between the shared holders
//!   (`prepare`'s index update), waiting up to a timeout.

use std::fs::File;
use std::os::unix::fs::FileExt;
use std::os::unix::io::AsRawFd;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// The lock file inside an output folder.
pub const LOCK_FILE: &str = ".depthsense.lock";

/// Bytes of the holder record (fixed, so that concurrent shared holders each write a whole one).
const RECORD_LEN: usize = 256;

/// Who holds (or last held) a lock, as its record says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Holder {
    pub pid: u32,
    /// UTC, `YYYY-MM-DD HH:MM:SS UTC`.
    pub started: String,
    /// What the process does, e.g. `depthsense train`.
    pub command: String,
}

impl std::fmt::Display for Holder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "pid {}, `{}`, started {}",
            self.pid, self.command, self.started
        )
    }
}

#[derive(Debug, thiserror::Error)]
pub enum LockError {
    #[error(
        "another depthsense process ({}) is writing {}; wait for it to finish or stop it \
         (a killed process leaves no lock behind)",
        .holder.as_ref().map_or("pid unknown".to_string(), |h| h.to_string()),
        .dir.display()
    )]
    Held {
        dir: PathBuf,
        holder: Option<Holder>,
    },
    #[error(
        "{}: still held by another depthsense process ({}) after {} s",
        .path.display(),
        .holder.as_ref().map_or("pid unknown".to_string(), |h| h.to_string()),
        .waited.as_secs()
    )]
    Timeout {
        path: PathBuf,
        holder: Option<Holder>,
        waited: Duration,
    },
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// A held lock; released when dropped (the file is closed) or when the process ends.
#[derive(Debug)]
pub struct OutputLock {
    file: File,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    Exclusive,
    Shared,
}

impl OutputLock {
    /// The exclusive lock of `dir` (created if missing), or [`LockError::Held`] at once.
    /// `command` says what the holder does (`depthsense train`), for the other's message.
    pub fn exclusive(dir: &Path, command: &str) -> Result<Self, LockError> {
        Self::take(dir, &dir.join(LOCK_FILE), Kind::Exclusive, command)
    }

    /// A shared lock of `dir`: other shared holders are welcome, an exclusive one is not.
    pub fn shared(dir: &Path, command: &str) -> Result<Self, LockError> {
        Self::take(dir, &dir.join(LOCK_FILE), Kind::Shared, command)
    }

    /// The exclusive lock of the file `path` (created if missing), waiting up to `timeout`
    /// for the current holder.
    pub fn wait_exclusive(
        path: &Path,
        command: &str,
        timeout: Duration,
    ) -> Result<Self, LockError> {
        let start = Instant::now();
        let dir = path.parent().unwrap_or(Path::new("."));
        loop {
            match Self::take(dir, path, Kind::Exclusive, command) {
                Err(LockError::Held { holder, .. }) => {
                    if start.elapsed() >= timeout {
                        return Err(LockError::Timeout {
                            path: path.to_path_buf(),
                            holder,
                            waited: start.elapsed(),
                        });
                    }
                    std::thread::sleep(Duration::from_millis(20));
                }
                other => return other,
            }
        }
    }

    fn take(dir: &Path, path: &Path, kind: Kind, command: &str) -> Result<Self, LockError> {
        let io = |source| LockError::Io {
            path: path.to_path_buf(),
            source,
        };
        std::fs::create_dir_all(dir).map_err(|e| LockError::Io {
            path: dir.to_path_buf(),
            source: e,
        })?;
        // Not truncated on open: the record of a running holder stays readable.
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)
            .map_err(io)?;
        let op = match kind {
            Kind::Exclusive => libc::LOCK_EX,
            Kind::Shared => libc::LOCK_SH,
        } | libc::LOCK_NB;
        // SAFETY: flock on a file descriptor this function owns.
        if unsafe { libc::flock(file.as_raw_fd(), op) } != 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::WouldBlock {
                return Err(LockError::Held {
                    dir: dir.to_path_buf(),
                    holder: read_holder(path),
                });
            }
            return Err(io(e));
        }
        let record = record(std::process::id(), &utc_now(), command);
        file.write_all_at(&record, 0).map_err(io)?;
        Ok(OutputLock { file })
    }

    /// Whether `dir` is locked by a live process now (without taking anything).
    pub fn is_held(dir: &Path) -> bool {
        let path = dir.join(LOCK_FILE);
        let Ok(file) = File::open(&path) else {
            return false;
        };
        // SAFETY: as above; a shared probe released again at once.
        let r = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_SH | libc::LOCK_NB) };
        r != 0
    }
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // SAFETY: as above; closing the file would release it too.
        unsafe {
            libc::flock(self.file.as_raw_fd(), libc::LOCK_UN);
        }
    }
}

fn record(pid: u32, started: &str, command: &str) -> Vec<u8> {
    let text = format!("pid={pid}\nstarted={started}\ncommand={command}\n");
    let mut b: Vec<u8> = text.into_bytes();
    b.truncate(RECORD_LEN - 1);
    b.resize(RECORD_LEN - 1, b' ');
    b.push(b'\n');
    b
}

/// The holder record of a lock file, if readable.
pub fn read_holder(path: &Path) -> Option<Holder> {
    let text = std::fs::read_to_string(path).ok()?;
    let field = |k: &str| {
        text.lines()
            .find_map(|l| l.strip_prefix(k))
            .map(|v| v.trim().to_string())
    };
    Some(Holder {
        pid: field("pid=")?.parse().ok()?,
        started: field("started=").unwrap_or_else(|| "?".into()),
        command: field("command=").unwrap_or_else(|| "depthsense".into()),
    })
}

/// Now as `YYYY-MM-DD HH:MM:SS UTC`.
pub fn utc_now() -> String {
    let secs = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    utc_text(secs)
}

/// Seconds since 1970 as (year, month, day, hour, minute, second) in UTC (proleptic Gregorian
/// calendar; Howard Hinnant's civil_from_days).
fn utc_parts(secs: u64) -> (i64, i64, i64, u64, u64, u64) {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d, rem / 3600, rem / 60 % 60, rem % 60)
}

/// Seconds since 1970 as `YYYY-MM-DD HH:MM:SS UTC`.
pub fn utc_text(secs: u64) -> String {
    let (y, m, d, hh, mm, ss) = utc_parts(secs);
    format!("{y:04}-{m:02}-{d:02} {hh:02}:{mm:02}:{ss:02} UTC")
}

/// Seconds since 1970 as ISO 8601 in UTC, `YYYY-MM-DDTHH:MM:SSZ` (the time stamp of log lines).
pub fn utc_iso8601(secs: u64) -> String {
    let (y, m, d, hh, mm, ss) = utc_parts(secs);
    format!("{y:04}-{m:02}-{d:02}T{hh:02}:{mm:02}:{ss:02}Z")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_text_by_hand() {
        assert_eq!(utc_text(0), "1970-01-01 00:00:00 UTC");
        // 2026-12-02 17:42:23 UTC (date -u -d @1796233343)
        assert_eq!(utc_text(1_796_233_343), "2026-12-02 17:42:23 UTC");
        // 2000-02-29 (leap day of a century leap year)
        assert_eq!(utc_text(951_782_400), "2000-02-29 00:00:00 UTC");
    }

    #[test]
    fn exclusive_is_exclusive_and_names_the_holder() {
        let d = tempfile::tempdir().unwrap();
        let a = OutputLock::exclusive(d.path(), "depthsense train").unwrap();
        // flock is per open file description: a second open in this process conflicts too.
        let e = OutputLock::exclusive(d.path(), "depthsense train").unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains(&format!("pid {}", std::process::id()))
                && msg.contains("`depthsense train`")
                && msg.contains(&d.path().display().to_string())
                && msg.starts_with("another depthsense process"),
            "{msg}"
        );
        assert!(OutputLock::is_held(d.path()));
        assert!(OutputLock::shared(d.path(), "depthsense prepare").is_err());
        drop(a);
        assert!(!OutputLock::is_held(d.path()));
        let _b = OutputLock::exclusive(d.path(), "depthsense train").unwrap();
    }

    #[test]
    fn shared_holders_coexist_and_keep_exclusive_out() {
        let d = tempfile::tempdir().unwrap();
        let a = OutputLock::shared(d.path(), "depthsense prepare").unwrap();
        let b = OutputLock::shared(d.path(), "depthsense prepare").unwrap();
        let e = OutputLock::exclusive(d.path(), "depthsense mer apply").unwrap_err();
        assert!(e.to_string().contains("`depthsense prepare`"), "{e}");
        drop((a, b));
        OutputLock::exclusive(d.path(), "depthsense mer apply").unwrap();
    }

    #[test]
    fn waiting_lock_times_out_then_succeeds_after_release() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join(".index.lock");
        let held = OutputLock::wait_exclusive(&p, "depthsense prepare", Duration::ZERO).unwrap();
        let e = OutputLock::wait_exclusive(&p, "x", Duration::from_millis(60)).unwrap_err();
        assert!(matches!(e, LockError::Timeout { .. }), "{e}");
        let t = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(50));
            drop(held);
        });
        OutputLock::wait_exclusive(&p, "x", Duration::from_secs(5)).unwrap();
        t.join().unwrap();
    }

    #[test]
    fn record_is_fixed_length_and_round_trips() {
        let r = record(42, "2026-12-02 17:42:23 UTC", "depthsense train");
        assert_eq!(r.len(), RECORD_LEN);
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join(LOCK_FILE);
        std::fs::write(&p, &r).unwrap();
        assert_eq!(
            read_holder(&p),
            Some(Holder {
                pid: 42,
                started: "2026-12-02 17:42:23 UTC".into(),
                command: "depthsense train".into()
            })
        );
        let long = record(1, "t", &"x".repeat(400));
        assert_eq!(long.len(), RECORD_LEN);
    }
}
