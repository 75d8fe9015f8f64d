//! Starting local workers as `torchrun --nproc-per-node N` does: a free loopback port for the
//! rendezvous ([`free_port`]) and the workers themselves, watched until every one has exited
//! ([`launch_local`]). Each failure is typed ([`LaunchError`], [`WorkerFailure`]) so that a
//! caller can tell a worker that failed from a launcher that could not start.
//!
//! A stop signal (SIGINT / SIGTERM, [`depthsense_base::interrupt`]) that reaches the launcher
//! is passed on to every worker once; the workers agree on the iteration, checkpoint and exit
//! with the signal's status, which is then a stop, not a failure. The workers run in their own
//! process group, so that a terminal's Ctrl-C reaches them only through the launcher, and each
//! gets SIGTERM should the launcher die.

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus};
use std::time::{Duration, Instant};

use depthsense_base::interrupt::{self, StopSignal};

/// Why a local job could not run or did not succeed.
#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    #[error("configuration: --nproc must be at least 1")]
    NoWorkers,
    #[error(
        "configuration: --nproc inside a distributed job (WORLD_SIZE is set): let torchrun / \
         srun start the workers, or drop --nproc"
    )]
    InsideJob,
    #[error("no free loopback port for MASTER_PORT: {0}")]
    NoPort(#[source] std::io::Error),
    #[error("cannot find this executable: {0}")]
    NoExecutable(#[source] std::io::Error),
    #[error("cannot start worker rank {rank} ({}): {source}", .exe.display())]
    Spawn {
        rank: usize,
        exe: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// Workers failed (every one is listed, the first to fail first).
    #[error("{} of {nproc} worker(s) failed: {}", .failed.len(), list(.failed))]
    WorkersFailed {
        nproc: usize,
        failed: Vec<WorkerFailure>,
    },
}

/// How one worker failed.
#[derive(Debug)]
pub enum WorkerFailure {
    /// It exited unsuccessfully (or was killed by a signal).
    Exited { rank: usize, status: ExitStatus },
    /// Its state could not be read.
    Wait { rank: usize, error: std::io::Error },
    /// Still running `grace` after the first failure: killed.
    Killed { rank: usize, grace: Duration },
}

impl WorkerFailure {
    pub fn rank(&self) -> usize {
        match self {
            WorkerFailure::Exited { rank, .. }
            | WorkerFailure::Wait { rank, .. }
            | WorkerFailure::Killed { rank, .. } => *rank,
        }
    }
}

impl std::fmt::Display for WorkerFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            WorkerFailure::Exited { rank, status } => write!(f, "rank {rank} ({status})"),
            WorkerFailure::Wait { rank, error } => write!(f, "rank {rank} (cannot wait: {error})"),
            WorkerFailure::Killed { rank, grace } => write!(
                f,
                "rank {rank} (killed {:.0} s after the first failure)",
                grace.as_secs_f64()
            ),
        }
    }
}

fn list(failed: &[WorkerFailure]) -> String {
    let parts: Vec<String> = failed.iter().map(ToString::to_string).collect();
    parts.join(", ")
}

/// A free TCP port on the loopback interface (for a local job's MASTER_PORT).
pub fn free_port() -> Result<u16, LaunchError> {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .map_err(LaunchError::NoPort)
}

/// Start `nproc` local workers of this executable with `args` and the environment torchrun
/// sets (RANK, LOCAL_RANK, WORLD_SIZE, LOCAL_WORLD_SIZE, GROUP_RANK, ROLE_RANK,
/// ROLE_WORLD_SIZE, MASTER_ADDR=127.0.0.1, MASTER_PORT), and wait for them. When a worker
/// fails, the others get `grace` to fail on their own (they name the peer that stopped), then
/// are killed. The error lists every failed worker. `Ok(Some(signal))`: the launcher received
/// a stop signal, passed it on, and every worker stopped for it.
pub fn launch_local(
    nproc: usize,
    args: &[OsString],
    master_port: Option<u16>,
    grace: Duration,
) -> Result<Option<StopSignal>, LaunchError> {
    if nproc == 0 {
        return Err(LaunchError::NoWorkers);
    }
    if std::env::var_os("WORLD_SIZE").is_some() {
        return Err(LaunchError::InsideJob);
    }
    let exe = std::env::current_exe().map_err(LaunchError::NoExecutable)?;
    let port = match master_port {
        Some(p) => p,
        None => free_port()?,
    };
    let children = spawn_workers(&exe, nproc, args, port)?;
    let (failed, stopped) = wait_workers(children, grace);
    if failed.is_empty() {
        Ok(stopped)
    } else {
        Err(LaunchError::WorkersFailed { nproc, failed })
    }
}

/// Every worker started, or none left running.
fn spawn_workers(
    exe: &PathBuf,
    nproc: usize,
    args: &[OsString],
    port: u16,
) -> Result<Vec<(usize, Child)>, LaunchError> {
    let mut children: Vec<(usize, Child)> = Vec::with_capacity(nproc);
    for rank in 0..nproc {
        let mut command = Command::new(exe);
        {
            use std::os::unix::process::CommandExt;
            command.process_group(0);
            // SAFETY: prctl(2) is async-signal-safe; nothing else runs between fork and exec.
            unsafe {
                command.pre_exec(|| {
                    libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
                    Ok(())
                });
            }
        }
        let child = command
            .args(args)
            .env("RANK", rank.to_string())
            .env("LOCAL_RANK", rank.to_string())
            .env("WORLD_SIZE", nproc.to_string())
            .env("LOCAL_WORLD_SIZE", nproc.to_string())
            .env("GROUP_RANK", "0")
            .env("ROLE_RANK", rank.to_string())
            .env("ROLE_WORLD_SIZE", nproc.to_string())
            .env("MASTER_ADDR", "127.0.0.1")
            .env("MASTER_PORT", port.to_string())
            .spawn();
        match child {
            Ok(c) => children.push((rank, c)),
            Err(source) => {
                for (_, c) in children.iter_mut() {
                    let _ = c.kill();
                    let _ = c.wait();
                }
                return Err(LaunchError::Spawn {
                    rank,
                    exe: exe.clone(),
                    source,
                });
            }
        }
    }
    Ok(children)
}

/// Wait for every worker; the failures, the first first, and the stop signal passed on to the
/// workers (a worker that exited with that signal's status after it stopped, not failed).
fn wait_workers(
    mut running: Vec<(usize, Child)>,
    grace: Duration,
) -> (Vec<WorkerFailure>, Option<StopSignal>) {
    let mut failed = vec![];
    let mut first_failure: Option<Instant> = None;
    let mut passed_on: Option<StopSignal> = None;
    while !running.is_empty() {
        if let (None, Some(sig)) = (passed_on, interrupt::requested()) {
            for (_, c) in &running {
                // SAFETY: kill(2) of our own child's pid (not reaped yet: try_wait reaps).
                unsafe { libc::kill(c.id() as libc::pid_t, sig.number()) };
            }
            passed_on = Some(sig);
        }
        let mut still = vec![];
        for (rank, mut c) in running {
            match c.try_wait() {
                Ok(Some(status))
                    if passed_on.is_some_and(|s| status.code() == Some(s.exit_code().into())) => {}
                Ok(Some(status)) if !status.success() => {
                    failed.push(WorkerFailure::Exited { rank, status });
                    first_failure.get_or_insert_with(Instant::now);
                }
                Ok(Some(_)) => {}
                Ok(None) => still.push((rank, c)),
                Err(error) => {
                    failed.push(WorkerFailure::Wait { rank, error });
                    first_failure.get_or_insert_with(Instant::now);
                }
            }
        }
        running = still;
        if first_failure.is_some_and(|t| t.elapsed() > grace) {
            for (rank, c) in running.iter_mut() {
                let _ = c.kill();
                let _ = c.wait();
                failed.push(WorkerFailure::Killed { rank: *rank, grace });
            }
            running.clear();
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    (failed, passed_on)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::process::ExitStatusExt;

    #[test]
    fn the_failures_read_as_before() {
        let e = LaunchError::WorkersFailed {
            nproc: 3,
            failed: vec![
                WorkerFailure::Exited {
                    rank: 1,
                    status: ExitStatus::from_raw(2 << 8),
                },
                WorkerFailure::Killed {
                    rank: 0,
                    grace: Duration::from_secs(30),
                },
            ],
        };
        assert_eq!(
            e.to_string(),
            "2 of 3 worker(s) failed: rank 1 (exit status: 2), rank 0 (killed 30 s after the \
             first failure)"
        );
        let LaunchError::WorkersFailed { failed, .. } = &e else {
            unreachable!()
        };
        assert_eq!(
            failed.iter().map(WorkerFailure::rank).collect::<Vec<_>>(),
            [1, 0]
        );
    }

    #[test]
    fn no_workers_are_refused_before_anything_starts() {
        let e = launch_local(0, &[], None, Duration::ZERO).unwrap_err();
        assert!(matches!(e, LaunchError::NoWorkers), "{e}");
        assert_eq!(e.to_string(), "configuration: --nproc must be at least 1");
    }

    #[test]
    fn a_free_port_is_bindable() {
        let p = free_port().unwrap();
        assert!(p > 0);
        std::net::TcpListener::bind(("127.0.0.1", p)).unwrap();
    }
}
