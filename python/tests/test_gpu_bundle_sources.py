"""scripts/gpu-check.sh refuses a bundle built from other sources than the tree it arrives with
(.gpu/sources.txt, written by `make gpu-bundle`), in seconds and naming the files — before any
GPU time is spent on old code."""
import hashlib
import json
import os
import shutil
import subprocess
import sys

SCRIPT = os.path.join(os.path.dirname(__file__), "..", "..", "scripts", "gpu-check.sh")


def fake_tree(tmp_path, listed_content):
    """A tree with Cargo.lock and crates/a.rs, and .gpu/ holding the script and a listing of
    crates/a.rs's digest when it held `listed_content`."""
    gpu = tmp_path / ".gpu"
    (tmp_path / "crates").mkdir()
    gpu.mkdir()
    (tmp_path / "Cargo.lock").write_text("# lock\n")
    (tmp_path / "crates" / "a.rs").write_text("fn a() {}\n")
    shutil.copy(SCRIPT, gpu / "gpu-check.sh")
    digest = hashlib.sha256(listed_content.encode()).hexdigest()
    (gpu / "sources.txt").write_text(f"{digest}  crates/a.rs\n")
    return gpu


def run(gpu, tmp_path):
    # The interpreter without the venv's packages: both checks come before torch is needed,
    # and the script's two imports of torch would take most of the test's time.
    python = getattr(sys, "_base_executable", sys.executable)
    env = dict(os.environ, PYTHON=python, DEPTHSENSE_BIN="/bin/true")
    out = tmp_path / "out"
    p = subprocess.run(["bash", str(gpu / "gpu-check.sh"), "--cpu-dry-run", "--out", str(out)],
                       capture_output=True, text=True, env=env, timeout=120)
    fatal = json.loads((out / "env.json").read_text())["fatal"]
    return p.returncode, fatal


def test_a_bundle_of_other_sources_is_refused_naming_the_file(tmp_path):
    gpu = fake_tree(tmp_path, "fn a() { old }\n")
    rc, fatal = run(gpu, tmp_path)
    assert rc == 3
    assert "built from other sources" in fatal and "1 files differ: crates/a.rs" in fatal, fatal


def test_a_bundle_of_these_sources_passes_the_check(tmp_path):
    gpu = fake_tree(tmp_path, "fn a() {}\n")
    rc, fatal = run(gpu, tmp_path)
    # The next check stops it (no torch_reference.py in this fake bundle): past the sources.
    assert rc == 3 and "torch_reference" in fatal, fatal
