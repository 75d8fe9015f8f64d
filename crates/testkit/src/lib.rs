//! Test support shared by every crate of the workspace (a dev-dependency only, no dependencies
//! of its own, so it sits below every layer).
//!
//! **Skips are counted, never silent.** A test that cannot run calls [`skip`] (or one of the
//! helpers below, which do): the reason goes to stderr and, when `DEPTHSENSE_SKIP_LOG` names a
//! file, one line `test<TAB>reason` is appended to it. `make test` sets that variable and prints
//! one summary line at the end (`scripts/skip-summary.sh`).
//!
//! **Required tools fail instead of skipping.** Each optional tool has a switch, set by
//! `make test`, under which its absence is a test failure with a clear message:
//!
//! | tool | switch | helper |
//! |---|---|---|
//! | torch in `.venv/` | `DEPTHSENSE_REQUIRE_TORCH=1` | [`python_with_torch`] |
//! | nuscenes-devkit in `.venv/` | `DEPTHSENSE_REQUIRE_DEVKIT=1` | [`python_with_devkit`] |
//! | Chromium | `DEPTHSENSE_REQUIRE_BROWSER=1` (`make test-browser`) | [`unavailable`] |
//!
//! The shared fixtures (`../shared/fixtures/`, outside the repository) are data, not a tool:
//! their absence is a counted skip ([`fixture`]).

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus};
use std::time::{Duration, Instant};

/// Environment variable naming the file that collects one line per skipped test.
pub const SKIP_LOG_ENV: &str = "DEPTHSENSE_SKIP_LOG";
/// Under `=1`, a missing or broken torch in `.venv/` fails the test.
pub const REQUIRE_TORCH: &str = "DEPTHSENSE_REQUIRE_TORCH";
/// Under `=1`, a missing nuscenes-devkit in `.venv/` fails the test.
pub const REQUIRE_DEVKIT: &str = "DEPTHSENSE_REQUIRE_DEVKIT";
/// Under `=1`, a missing Chromium fails the browser test.
pub const REQUIRE_BROWSER: &str = "DEPTHSENSE_REQUIRE_BROWSER";

/// The workspace root (this crate lives in `crates/testkit`).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// `../shared/fixtures/` beside the repository.
pub fn fixtures_root() -> PathBuf {
    workspace_root().join("../shared/fixtures")
}

/// The name libtest gives the running test (its thread's name), else the executable's.
fn test_name() -> String {
    let exe = std::env::current_exe()
        .ok()
        .and_then(|p| p.file_stem().map(|s| s.to_string_lossy().into_owned()))
        .map(|s| match s.rsplit_once('-') {
            // cargo's test binaries are `<target>-<16 hex>`
            Some((name, hash)) if hash.len() == 16 => name.to_string(),
            _ => s,
        })
        .unwrap_or_else(|| "?".into());
    match std::thread::current().name() {
        Some(t) if t != "main" => format!("{exe}::{t}"),
        _ => exe,
    }
}

/// Records that the running test skips (stderr, plus the skip log when one is set).
pub fn skip(reason: &str) {
    let name = test_name();
    eprintln!("SKIP {name}: {reason}");
    let Some(log) = std::env::var_os(SKIP_LOG_ENV) else {
        return;
    };
    let line = format!("{name}\t{}\n", reason.replace(['\n', '\t'], " "));
    // One short O_APPEND write per line: concurrent tests do not interleave.
    let res = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log)
        .and_then(|mut f| f.write_all(line.as_bytes()));
    if let Err(e) = res {
        panic!(
            "cannot append to the skip log {}: {e}",
            Path::new(&log).display()
        );
    }
}

/// Whether `var` is set to `1`.
pub fn required(var: &str) -> bool {
    std::env::var(var).is_ok_and(|v| v == "1")
}

/// The test cannot run because `reason`: a failure under `var=1`, else a counted skip.
/// Returns `None` so that callers can `let Some(x) = … else { return }`.
pub fn unavailable<T>(var: &str, reason: &str) -> Option<T> {
    if required(var) {
        panic!("{var}=1 but {reason}");
    }
    skip(reason);
    None
}

/// A shared fixture under `../shared/fixtures/`, or `None` after a counted skip.
pub fn fixture(name: &str) -> Option<PathBuf> {
    let p = fixtures_root().join(name);
    if p.exists() {
        Some(p)
    } else {
        skip(&format!("fixture absent at {}", p.display()));
        None
    }
}

/// The workspace's `.venv/bin/python` (`$VIRTUAL_ENV/bin/python` when set).
pub fn venv_python() -> PathBuf {
    match std::env::var_os("VIRTUAL_ENV") {
        Some(v) => PathBuf::from(v).join("bin/python"),
        None => workspace_root().join(".venv/bin/python"),
    }
}

/// The venv's Python when it can import every module of `modules` (`python -c "import …"`),
/// else a failure under `var=1` or a counted skip. The message carries Python's own error.
pub fn python_with(modules: &[&str], var: &str) -> Option<PathBuf> {
    let py = venv_python();
    if !py.exists() {
        return unavailable(
            var,
            &format!("no Python at {} (run `make setup`)", py.display()),
        );
    }
    let code = format!("import {}", modules.join(", "));
    match Command::new(&py).args(["-c", &code]).output() {
        Ok(o) if o.status.success() => Some(py),
        Ok(o) => {
            let err = String::from_utf8_lossy(&o.stderr);
            let last = err.lines().last().unwrap_or("").trim().to_string();
            unavailable(
                var,
                &format!(
                    "{} cannot `{code}`: {last} (run `make setup`)",
                    py.display()
                ),
            )
        }
        Err(e) => unavailable(var, &format!("cannot run {}: {e}", py.display())),
    }
}

/// The venv's Python with torch and numpy (switch `DEPTHSENSE_REQUIRE_TORCH`).
pub fn python_with_torch() -> Option<PathBuf> {
    python_with(&["torch", "numpy"], REQUIRE_TORCH)
}

/// The venv's Python with the official nuScenes devkit (switch `DEPTHSENSE_REQUIRE_DEVKIT`).
pub fn python_with_devkit() -> Option<PathBuf> {
    python_with(&["numpy", "nuscenes.nuscenes"], REQUIRE_DEVKIT)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn skip_lines_name_the_test_and_the_reason() {
        let dir = std::env::temp_dir().join(format!("testkit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let log = dir.join("skips.log");
        // The variable is process-wide: this crate has one test touching it.
        std::env::set_var(SKIP_LOG_ENV, &log);
        skip("a reason\twith a tab");
        let missing: Option<()> = unavailable("DEPTHSENSE_TESTKIT_NEVER_SET", "no tool");
        std::env::remove_var(SKIP_LOG_ENV);
        assert!(missing.is_none());
        let text = std::fs::read_to_string(&log).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 2, "{text}");
        assert!(
            lines[0].ends_with("skip_lines_name_the_test_and_the_reason\ta reason with a tab"),
            "{}",
            lines[0]
        );
        assert!(lines[1].ends_with("\tno tool"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    #[should_panic(expected = "DEPTHSENSE_TESTKIT_REQUIRED=1 but the tool is missing")]
    fn a_required_tool_fails_the_test() {
        // Set and read within this thread only; no other test uses this variable.
        std::env::set_var("DEPTHSENSE_TESTKIT_REQUIRED", "1");
        let _: Option<()> = unavailable("DEPTHSENSE_TESTKIT_REQUIRED", "the tool is missing");
    }
}

/// Environment variable under which a test binary runs one test alone ([`run_alone`]).
const ALONE_ENV: &str = "DEPTHSENSE_TEST_ALONE";

/// Runs the calling test alone, in a child process of this test binary (`--exact TEST
/// --test-threads=1`), for a test whose outcome depends on the values it draws from libtorch's
/// process-wide generator after `manual_seed`: beside the other tests of the binary, which draw
/// from the same generator at the same time, those values change from run to run.
///
/// `test` is the test's path within the binary (`module::name`). Returns `true` in the child —
/// run the test's body — and `false` in the parent once the child passed; the child's failure,
/// a name that matches no test, or `timeout` passing (the child is killed) fail the parent with
/// the child's output.
pub fn run_alone(test: &str, timeout: Duration) -> bool {
    if std::env::var(ALONE_ENV).as_deref() == Ok(test) {
        return true;
    }
    let exe = std::env::current_exe().expect("the test binary's path");
    let mut child = Command::new(exe)
        .args(["--exact", test, "--test-threads=1"])
        .env(ALONE_ENV, test)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("start the test binary again");
    // Read both pipes while the child runs, so that a full pipe cannot stall it.
    let stdout = drain(child.stdout.take());
    let stderr = drain(child.stderr.take());
    let Some(status) = wait_within(&mut child, timeout) else {
        panic!("{test} alone: still running after {timeout:?}, killed");
    };
    let (stdout, stderr) = (
        stdout.join().unwrap_or_default(),
        stderr.join().unwrap_or_default(),
    );
    assert!(
        status.success() && stdout.contains("test result: ok. 1 passed"),
        "{test} alone: {status}\n{stdout}\n{stderr}"
    );
    false
}

/// Waits for `child` at most `limit`: its exit status, or `None` once `limit` has passed (the
/// child is then killed and reaped). The multi-process tests' deadline.
pub fn wait_within(child: &mut Child, limit: Duration) -> Option<ExitStatus> {
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("wait for a child process") {
            return Some(status);
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A thread reading `pipe` to its end (a child's stdout or stderr).
fn drain<R: Read + Send + 'static>(pipe: Option<R>) -> std::thread::JoinHandle<String> {
    std::thread::spawn(move || {
        let mut text = String::new();
        if let Some(mut p) = pipe {
            let _ = p.read_to_string(&mut text);
        }
        text
    })
}

#[cfg(test)]
mod alone_tests {
    use super::*;

    const LIMIT: Duration = Duration::from_secs(60);

    #[test]
    fn run_alone_runs_the_body_in_a_child() {
        let me = "alone_tests::run_alone_runs_the_body_in_a_child";
        if !run_alone(me, LIMIT) {
            return;
        }
        assert_eq!(std::env::var(ALONE_ENV).as_deref(), Ok(me));
    }

    /// Passes in the parent; fails when run alone (for the test below).
    #[test]
    fn fails_when_alone() {
        if std::env::var(ALONE_ENV).as_deref() == Ok("alone_tests::fails_when_alone") {
            panic!("fails on purpose when alone");
        }
    }

    #[test]
    fn run_alone_fails_with_the_child_or_a_name_of_no_test() {
        for name in ["alone_tests::fails_when_alone", "alone_tests::no_such_test"] {
            let r = std::panic::catch_unwind(|| run_alone(name, LIMIT));
            assert!(r.is_err(), "{name}");
        }
    }
}
