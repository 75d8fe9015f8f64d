#!/usr/bin/env python3
"""`make test`'s runner of the Rust test binaries: two at once, where `cargo test` runs them one
after another.

One binary rarely keeps both cores busy: its last long test runs alone, and most small binaries
are a single test. Two at once, longest first, fill those gaps (clean clone, 2-core EPYC VM: the
Rust tests 264 s → 218 s wall, all passing).

    cargo test --workspace --no-run --message-format=json-render-diagnostics > BINARIES.json
    scripts/run-tests.py BINARIES.json [--jobs N] [-- ARGS FOR EVERY BINARY]

Each binary runs as `cargo test` runs it (in its package's folder, with the environment given
here); its output goes to target/test-logs/NAME.log and is printed whole when it ends, after a
`Running` line as cargo's; while binaries run, a `Waiting` line each minute names them. The
last lines count the tests and name every failed binary with the cargo command that reruns it.
Exit status 1 when any failed. Each run's durations go to
target/test-times.json and order the next run, longest first; a clean clone starts with the
binaries known to be long (LONG_FIRST). Doc-tests are not here: `cargo test --doc`.
"""

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

# Known to run longest (seconds on the 2-core VM): the order of a clean clone without
# target/test-times.json. Only the order depends on it.
LONG_FIRST = {"test:cli": 72, "test:experiments": 46, "test:export": 45, "test:model": 32}

# Seconds between the "still running" lines (the environment can shorten it: tests).
HEARTBEAT_S = float(os.environ.get("RUN_TESTS_HEARTBEAT_S", "60"))

RESULT = re.compile(r"test result: (\w+)\. (\d+) passed; (\d+) failed; (\d+) ignored")


class Binary:
    def __init__(self, msg, root, logs):
        self.exe = Path(msg["executable"])
        self.cwd = Path(msg["manifest_path"]).parent
        target = msg["target"]
        self.kind = target["kind"][0]
        self.name = target["name"]
        self.src = Path(target["src_path"])
        # package_id: "path+file:///…/crates/cli#depthsense-cli@0.1.0" (or "…#0.1.0" when the
        # folder's name is the package's).
        pid = msg["package_id"]
        tail = pid.rsplit("#", 1)[-1]
        self.package = tail.split("@")[0] if "@" in tail else pid.rsplit("/", 1)[-1].split("#")[0]
        self.root = root
        self.key = f"{'lib' if self.kind in ('lib', 'rlib', 'cdylib') else self.kind}:{self.name}"
        self.log = logs / f"{self.package}-{self.kind}-{self.name}.log"
        self.rc = None
        self.seconds = 0.0
        self.counts = [0, 0, 0]  # passed, failed, ignored

    def rel(self, p):
        try:
            return p.relative_to(self.root)
        except ValueError:
            return p

    def rerun(self):
        which = "--lib" if self.key.startswith("lib:") else f"--{self.kind} {self.name}"
        return f"cargo test -p {self.package} {which}"


def binaries(json_file, root, logs):
    seen, out = set(), []
    for line in Path(json_file).read_text().splitlines():
        if not line.startswith("{"):
            continue
        msg = json.loads(line)
        if msg.get("reason") != "compiler-artifact" or not msg.get("executable"):
            continue
        if not msg.get("profile", {}).get("test"):
            continue
        if msg["executable"] in seen:
            continue
        seen.add(msg["executable"])
        out.append(Binary(msg, root, logs))
    return out


def run_one(b, args, env, children, lock):
    b.log.parent.mkdir(parents=True, exist_ok=True)
    t = time.monotonic()
    with open(b.log, "wb") as log:
        p = subprocess.Popen(
            [str(b.exe), *args], cwd=b.cwd, env=env, stdout=log, stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        with lock:
            children.add(p)
        b.rc = p.wait()
        with lock:
            children.discard(p)
    b.seconds = time.monotonic() - t
    text = b.log.read_text(errors="replace")
    for m in RESULT.finditer(text):
        for i in range(3):
            b.counts[i] += int(m.group(i + 2))
    return text


def main():
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="After --: arguments for every test binary (a test-name filter, --nocapture, …).",
    )
    ap.add_argument("binaries", help="cargo test --no-run --message-format=json(-render-diagnostics) output")
    ap.add_argument("--jobs", type=int, default=2, help="test binaries at once (default 2)")
    ap.add_argument("--logs", type=Path, help="each binary's output (default target/test-logs)")
    ap.add_argument("--times", type=Path, help="durations, read and rewritten (default target/test-times.json)")
    argv = sys.argv[1:]
    cut = argv.index("--") if "--" in argv else len(argv)
    a = ap.parse_args(argv[:cut])
    a.args = argv[cut + 1:]  # after --: arguments for every binary
    root = Path(__file__).resolve().parent.parent
    todo = binaries(a.binaries, root, a.logs or root / "target" / "test-logs")
    if not todo:
        print(f"run-tests: no test binaries in {a.binaries}: was it written by "
              "`cargo test --no-run --message-format=json-render-diagnostics`?", file=sys.stderr)
        return 2
    times_file = a.times or root / "target" / "test-times.json"
    try:
        times = json.loads(times_file.read_text())
    except (OSError, ValueError):
        times = {}
    todo.sort(key=lambda b: -times.get(b.key, LONG_FIRST.get(b.key, 0.0)))

    env = dict(os.environ)
    lock, children, failed, running = threading.Lock(), set(), [], {}
    queue = list(todo)
    t0 = time.monotonic()
    last_beat = [t0]

    def worker():
        while True:
            with lock:
                if not queue:
                    return
                b = queue.pop(0)
                running[b.name] = time.monotonic()
                print(f"     Started {b.rel(b.src)} ({b.package})", flush=True)
            text = run_one(b, a.args, env, children, lock)
            with lock:
                running.pop(b.name, None)
                print(f"     Running {b.rel(b.src)} ({b.rel(b.exe)}) — {b.seconds:.1f} s", flush=True)
                sys.stdout.write(text if text.endswith("\n") or not text else text + "\n")
                sys.stdout.flush()
                if b.rc != 0:
                    failed.append(b)

    def stop(signum, _frame):
        with lock:
            queue.clear()
            for p in children:
                try:
                    os.killpg(p.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        print(f"run-tests: stopped by signal {signum}; logs in {todo[0].log.parent}", file=sys.stderr)
        os._exit(130)

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    threads = [threading.Thread(target=worker, daemon=True) for _ in range(max(1, a.jobs))]
    for t in threads:
        t.start()
    # A line a minute while binaries run (their own output comes when each ends).
    while any(t.is_alive() for t in threads):
        time.sleep(min(1.0, HEARTBEAT_S))
        with lock:
            now = time.monotonic()
            if running and now - last_beat[0] >= HEARTBEAT_S:
                last_beat[0] = now
                names = ", ".join(f"{n} ({now - t:.0f} s)" for n, t in running.items())
                print(f"     Waiting {now - t0:.0f} s in: still running {names}", flush=True)

    wall = time.monotonic() - t0
    passed, nfail, ignored = (sum(b.counts[i] for b in todo) for i in range(3))
    times.update({b.key: round(b.seconds, 1) for b in todo})
    tmp = times_file.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(times, indent=1, sort_keys=True) + "\n")
    tmp.replace(times_file)
    print(f"run-tests: {len(todo)} test binaries, {a.jobs} at once, in {wall:.0f} s: "
          f"{passed} passed, {nfail} failed, {ignored} ignored")
    for b in failed:
        print(f"run-tests: FAILED {b.rel(b.src)} (exit {b.rc}; log {b.rel(b.log)}); rerun: {b.rerun()}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
