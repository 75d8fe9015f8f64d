"""scripts/run-tests.py: make test's runner of the Rust test binaries, two at once."""
import json
import os
import subprocess
import sys

SCRIPT = os.path.join(os.path.dirname(__file__), "..", "..", "scripts", "run-tests.py")


def fake_binary(tmp_path, name, passed, failed, seconds=0.0):
    """A shell script that prints what a libtest binary prints, in its package folder."""
    pkg = tmp_path / name
    pkg.mkdir()
    (pkg / "Cargo.toml").write_text("")
    exe = pkg / f"{name}-0123"
    result = "FAILED" if failed else "ok"
    exe.write_text(
        "#!/bin/sh\n"
        f"sleep {seconds}\n"
        'echo "cwd $(pwd) args $*"\n'
        f'echo "test result: {result}. {passed} passed; {failed} failed; 1 ignored; 0 measured"\n'
        f"exit {101 if failed else 0}\n"
    )
    exe.chmod(0o755)
    return {
        "reason": "compiler-artifact",
        "package_id": f"path+file://{pkg}#depthsense-{name}@0.1.0",
        "manifest_path": str(pkg / "Cargo.toml"),
        "target": {"kind": ["test"], "name": name, "src_path": str(pkg / "tests" / "main.rs")},
        "profile": {"test": True},
        "executable": str(exe),
    }


def run(tmp_path, msgs, *extra, env=None):
    listing = tmp_path / "binaries.json"
    lines = [json.dumps(m) for m in msgs] + ['{"reason":"build-finished","success":true}']
    listing.write_text("\n".join(lines) + "\n")
    cmd = [sys.executable, SCRIPT, str(listing), "--logs", str(tmp_path / "logs"),
           "--times", str(tmp_path / "times.json"), *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=60,
                          env={**os.environ, **(env or {})})


def test_counts_every_binary_and_names_the_failed_one_with_its_rerun(tmp_path):
    msgs = [fake_binary(tmp_path, "good", 3, 0), fake_binary(tmp_path, "bad", 2, 1)]
    p = run(tmp_path, msgs, "--", "--skip", "slow")
    assert p.returncode == 1, p.stdout + p.stderr
    assert "2 test binaries, 2 at once" in p.stdout and "5 passed, 1 failed, 2 ignored" in p.stdout
    assert "rerun: cargo test -p depthsense-bad --test bad" in p.stdout
    assert "rerun: cargo test -p depthsense-good" not in p.stdout
    # Each binary ran in its package folder with the arguments after --, its output whole.
    assert f"cwd {tmp_path / 'good'} args --skip slow" in p.stdout
    assert (tmp_path / "logs" / "depthsense-bad-test-bad.log").read_text().startswith("cwd ")
    times = json.loads((tmp_path / "times.json").read_text())
    assert set(times) == {"test:good", "test:bad"}


def test_all_passing_is_exit_0_and_the_last_durations_order_the_next_run(tmp_path):
    msgs = [fake_binary(tmp_path, "short", 1, 0), fake_binary(tmp_path, "long", 1, 0, 1.0)]
    (tmp_path / "times.json").write_text(json.dumps({"test:short": 1.0, "test:long": 9.0}))
    p = run(tmp_path, msgs, "--jobs", "1", env={"RUN_TESTS_HEARTBEAT_S": "0.2"})
    assert p.returncode == 0, p.stdout + p.stderr
    assert "still running long (" in p.stdout, "a line while a binary runs"
    started = [ln.split()[1] for ln in p.stdout.splitlines() if ln.strip().startswith("Started")]
    assert [os.path.basename(os.path.dirname(os.path.dirname(s))) for s in started] == ["long", "short"]
    assert json.loads((tmp_path / "times.json").read_text())["test:long"] >= 1.0


def test_a_listing_without_binaries_is_refused(tmp_path):
    p = run(tmp_path, [])
    assert p.returncode == 2 and "no test binaries" in p.stderr
