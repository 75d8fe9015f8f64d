"""scripts/science_json.py plan: the science step's choice of mode and iterations (issue 45)."""
import json
import os
import subprocess
import sys

SCRIPT = os.path.join(os.path.dirname(__file__), "..", "..", "scripts", "science_json.py")


def plan(tmp_path, one, fours, **kw):
    (tmp_path / "probe_one.json").write_text(json.dumps({"train_images_per_s": one}))
    for k, r in enumerate(fours, 1):
        (tmp_path / f"probe_four_{k}.json").write_text(json.dumps({"train_images_per_s": r}))
    args = {"runs": 4, "batch": 8, "epochs": 4, "size": 3000, "time-left": 240,
            "run-overhead": 20, **kw}
    cmd = [sys.executable, SCRIPT, "plan", "--work", str(tmp_path)]
    for k, v in args.items():
        cmd += [f"--{k}", str(v)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    rec = json.loads((tmp_path / "plan.json").read_text())
    return p, rec


def test_four_at_once_when_the_probe_measures_ten_percent_more(tmp_path):
    p, rec = plan(tmp_path, 130.0, [40.0, 40.0, 40.0, 40.0])
    assert p.returncode == 0, p.stderr
    assert rec["mode"] == "parallel" and abs(rec["parallel_gain"] - 160 / 130) < 1e-9
    # (240 − 2·20) · 0.8 s at 160 images/s shared by 4 runs, batch 8, a multiple of 4.
    expect = int((200 * 0.8 * 160 / 4) // 8) // 4 * 4
    assert rec["iterations"] == expect and p.stdout.split() == ["parallel", str(expect), "3000"]


def test_one_after_another_otherwise_and_n_shrinks_to_one_pass(tmp_path):
    p, rec = plan(tmp_path, 130.0, [30.0, 30.0, 30.0, 30.0], **{"time-left": 150})
    assert p.returncode == 0, p.stderr
    assert rec["mode"] == "sequential"
    # (150 − 4·20) · 0.8 / 4 s per run at 130 images/s: fewer images than 3,000.
    expect = int((70 * 0.8 / 4 * 130) // 8) // 4 * 4
    assert rec["iterations"] == expect
    assert rec["size"] == expect * 8 < 3000, "N: what one pass of the iterations covers"


def test_no_time_is_an_error_not_a_zero_iteration_run(tmp_path):
    p, rec = plan(tmp_path, 130.0, [], **{"time-left": 60})
    assert p.returncode == 1 and "not enough time" in p.stderr
    assert rec["iterations"] == 0


def test_a_forced_mode_and_a_cap(tmp_path):
    p, rec = plan(tmp_path, 10.0, [1.0, 1.0, 1.0, 1.0], mode="parallel",
                  **{"max-iterations": 12, "size": 24, "batch": 2, "epochs": 2})
    assert p.returncode == 0, p.stderr
    assert (rec["mode"], rec["iterations"], rec["size"]) == ("parallel", 12, 24)


def test_four_at_once_is_rated_by_the_slowest_probe(tmp_path):
    # Summed, these probes claim 180 images/s (1.38× one process); their windows need not
    # overlap, so the plan counts four times the slowest, 120: less than one process alone.
    p, rec = plan(tmp_path, 130.0, [60.0, 40.0, 50.0, 30.0])
    assert p.returncode == 0, p.stderr
    assert rec["probe_four_images_per_s"] == 120.0 and rec["mode"] == "sequential"
    p, rec = plan(tmp_path, 100.0, [60.0, 40.0, 50.0, 30.0])
    assert rec["mode"] == "parallel" and abs(rec["parallel_gain"] - 1.2) < 1e-9


def test_runs_that_finished_are_recorded_when_the_table_is_missing(tmp_path):
    # The parallel stage ran out of time: rgb seed 0 finished in its own folder (eval.json,
    # best.safetensors), late-sam seed 0 wrote a best checkpoint before it was stopped; the
    # experiment's table (ds/data_scale.json) was never written.
    run = {"variant": "rgb", "seed": 0, "best_val_rmse": 9.5, "status": "trained",
           "rows": [{"condition": "combined", "region": "full", "rmse": 10.25, "n_images": 660}]}
    rgb = tmp_path / "ds_rgb_0" / "runs" / "n3000" / "rgb" / "seed0"
    sam = tmp_path / "ds_late-sam_0" / "runs" / "n3000" / "late-sam" / "seed0"
    for d in (rgb, sam):
        d.mkdir(parents=True)
    (rgb / "eval.json").write_text(json.dumps(run))
    (sam / "best.safetensors").write_bytes(b"x")
    (tmp_path / "stages.tsv").write_text("train\ttimeout after 300s\t300\n")
    out = tmp_path / "science.json"
    cmd = [sys.executable, SCRIPT, "write", "--work", str(tmp_path), "--out", str(out)]
    for k, v in {"dry": 0, "device": "cuda", "seed": 45, "scenes": 360,
                 "keyframes-per-scene": 12, "preset": "paper", "budget": 350, "t0": 0,
                 "rc": 1}.items():
        cmd += [f"--{k}", str(v)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    rec = json.loads(out.read_text())
    assert p.returncode == 1 and rec["ok"] is False
    assert [(r["arm"], r["seed"], r["test_rmse_m"]) for r in rec["runs"]] == [("rgb", 0, 10.25)]
    assert rec["runs_from"].startswith("eval.json") and rec["margin"]["margin_m"] is None
    assert rec["checkpoint_for_bf16"] == str(sam / "best.safetensors")
    assert "rgb       seed 0: test RMSE 10.250 m" in p.stdout
