#!/usr/bin/env python3
"""The science step's arithmetic and record (issue 45; run by scripts/gpu-science.sh).

  science_json.py plan  --work W --runs 4 --batch B --epochs E --size N --time-left S --run-overhead O
                        [--mode auto|parallel|sequential] [--max-iterations K]
      reads W/probe_one.json and W/probe_four_*.json (`depthsense bench train`), chooses one
      process at a time or four at once (four when four times the slowest of the four probes
      is ≥ 10 % more images per second than one process) and the largest
      iteration count that fits the time left; writes W/plan.json, prints "MODE ITERATIONS N".
  science_json.py write --work W --out FILE [...]
      science.json: the world, the plan, wall times, each run's test metrics and the margin of
      late-sam over rgb with its paired statistics (from the experiment's data_scale.json). The
      same keys on the CPU dry run and on the GPU; what is missing is null, never absent.

Standard library only: the GPU machine has Python without extra packages.
"""
import argparse
import glob
import json
import os
import sys
import time

SCHEMA = "depthsense-science/1"
# Four runs at once only when the probe measured at least this much more throughput.
PARALLEL_GAIN = 1.10
# The share of the time left that the plan spends on training steps (the rest: slack; a run
# that outlives the stage's timeout loses the whole science step, a shorter one only steps).
SAFETY = 0.8


def load(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def rate(report):
    r = (report or {}).get("train_images_per_s")
    return r if isinstance(r, (int, float)) and r > 0 else None


def plan(a):
    one = rate(load(os.path.join(a.work, "probe_one.json")))
    if one is None:
        print("probe_one.json has no train_images_per_s", file=sys.stderr)
        return 1
    fours = [rate(load(p)) for p in sorted(glob.glob(os.path.join(a.work, "probe_four_*.json")))]
    # Four at once: the slowest probe's rate, four times. Each probe times its own 20-step window
    # and the windows need not overlap, so their sum can count a probe that ran alone for a while.
    four = a.runs * min(fours) if len(fours) == a.runs and all(fours) else None
    gain = four / one if four else None
    mode = "parallel" if gain is not None and gain >= PARALLEL_GAIN else "sequential"
    if a.mode != "auto":
        mode = a.mode
    if mode == "parallel" and four is None:
        four = one  # forced without a four-process measurement: the rate of one, shared
    if mode == "parallel":
        # The runs' starts, validations and tests overlap; they share the GPU and the cores.
        train_s = (a.time_left - 2 * a.run_overhead) * SAFETY
        images_per_run = train_s * four / a.runs
    else:
        train_s = (a.time_left - a.runs * a.run_overhead) * SAFETY
        images_per_run = train_s / a.runs * one
    per = a.epochs
    iterations = int(max(images_per_run, 0) // a.batch) // per * per
    if a.max_iterations > 0:
        iterations = min(iterations, a.max_iterations)
    size = a.size
    # data-scale refuses fewer iterations than one pass over N: N shrinks to what fits.
    if iterations * a.batch < size:
        size = iterations * a.batch
    record = {"mode": mode, "iterations": iterations, "size": size, "size_asked": a.size,
              "probe_one_images_per_s": one, "probe_four_images_per_s": four,
              "probe_four_each": fours, "parallel_gain": gain, "mode_asked": a.mode,
              "parallel_gain_needed": PARALLEL_GAIN, "time_left_s": a.time_left,
              "run_overhead_s": a.run_overhead, "max_iterations": a.max_iterations or None, "safety": SAFETY,
              "planned_training_s": train_s, "batch_size": a.batch,
              "validations": a.epochs, "runs": a.runs}
    with open(os.path.join(a.work, "plan.json"), "w") as f:
        json.dump(record, f, indent=2)
    if iterations < per or size < a.batch:
        print(f"not enough time left ({a.time_left} s) for {a.runs} runs of "
              f"{per} validations", file=sys.stderr)
        return 1
    print(mode, iterations, size)
    return 0


def world_counts(index):
    """Keyframes and conditions per split, from the prepared index."""
    out = {}
    for split in ("train", "val", "test"):
        samples = [s for s in (index or {}).get("samples", []) if split in s.get("splits", [])]
        conds = {}
        for s in samples:
            for c in s.get("conditions", []):
                conds[c] = conds.get(c, 0) + 1
        out[split] = {"keyframes": len(samples), "scenes": len({s["scene_token"] for s in samples}),
                      "conditions": dict(sorted(conds.items()))}
    return out


def headline(run):
    for r in run.get("rows", []):
        if r.get("condition") == "combined" and r.get("region") == "full":
            return r
    return {}


def stat(s):
    return None if s is None else {"mean": s.get("mean"), "std": s.get("std"), "n": s.get("n")}


def margin_of(ds):
    """The late-sam row's margin over rgb, with the paired test of the RMSE."""
    row = next((r for r in (ds or {}).get("rows", []) if r.get("arm") == "late-sam"), None)
    base = next((r for r in (ds or {}).get("rows", []) if r.get("arm") == "rgb"), None)
    keys = ["margin_m", "margin_pct", "margin_se_m", "margin_se_pct", "t", "paired",
            "verdict", "seed_spread_m", "beyond_seed_spread", "finding"]
    if row is None:
        return {k: None for k in keys}
    verdict = row.get("vs_baseline") or {}
    paired = verdict.get("paired")
    spreads = [(r.get("rmse") or {}).get("std") for r in (row, base) if r]
    spreads = [s for s in spreads if s is not None]
    spread = max(spreads) if spreads else None
    m = (row.get("margin_m") or {}).get("mean")
    beyond = None if m is None or spread is None else abs(m) > spread
    significant = (paired or {}).get("significant")
    return {"margin_m": stat(row.get("margin_m")), "margin_pct": stat(row.get("margin_pct")),
            "margin_se_m": row.get("margin_se_m"), "margin_se_pct": row.get("margin_se_pct"),
            "t": row.get("margin_t"), "paired": paired, "verdict": verdict.get("text"),
            "seed_spread_m": spread, "beyond_seed_spread": beyond,
            "finding": None if significant is None or beyond is None
            else bool(significant and beyond)}


def write(a):
    w = a.work
    stages = []
    try:
        with open(os.path.join(w, "stages.tsv")) as f:
            for line in f:
                p = line.rstrip("\n").split("\t")
                if len(p) >= 3:
                    stages.append({"stage": p[0], "status": p[1], "seconds": int(p[2])})
    except OSError:
        pass
    plan_rec = load(os.path.join(w, "plan.json")) or {}
    ds = load(os.path.join(w, "ds", "data_scale.json"))
    index = load(os.path.join(w, "prepared", "index.json"))
    # Without the experiment's table (a stage that ran out of time), the runs that finished
    # still say what they measured: each run folder's eval.json holds the same record.
    run_records = (ds or {}).get("runs")
    runs_from = "ds/data_scale.json"
    if run_records is None:
        run_records = [load(p) or {} for p in
                       sorted(glob.glob(os.path.join(w, "ds*", "runs", "n*", "*", "seed*",
                                                     "eval.json")))]
        runs_from = "eval.json of each run that finished (no data_scale.json)"
    runs = []
    for r in run_records:
        h = headline(r)
        runs.append({"arm": r.get("variant"), "seed": r.get("seed"),
                     "test_rmse_m": h.get("rmse"), "test_mae_m": h.get("mae"),
                     "test_abs_rel": h.get("abs_rel"), "test_delta1": h.get("delta1"),
                     "test_images": h.get("n_images"), "best_val_rmse_m": r.get("best_val_rmse"),
                     "train_seconds": r.get("train_seconds"),
                     "eval_seconds": r.get("eval_seconds"), "status": r.get("status"),
                     "run_dir": r.get("run_dir")})
    arms = [{"arm": r.get("arm"), "train_samples": r.get("train_samples"),
             "passes": r.get("passes"), "test_rmse_m": stat(r.get("rmse")),
             "test_mae_m": stat(r.get("mae")), "test_abs_rel": stat(r.get("abs_rel")),
             "test_delta1": stat(r.get("delta1"))} for r in (ds or {}).get("rows", [])]
    # The gathered seed 0 first; else any late-sam run's best checkpoint (the runs' own folders
    # when the stage stopped before they were gathered).
    best = (sorted(glob.glob(os.path.join(w, "ds", "runs", "n*", "late-sam", "seed0",
                                          "best.safetensors")))
            or sorted(glob.glob(os.path.join(w, "ds*", "runs", "n*", "late-sam", "seed*",
                                             "best.safetensors"))))
    walls = {s["stage"]: s["seconds"] for s in stages}
    iterations = (ds or {}).get("iterations", plan_rec.get("iterations"))
    batch = plan_rec.get("batch_size")
    machine = (ds or {}).get("machine")
    rec = {
        "schema": SCHEMA,
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "dry_run": a.dry == "1",
        "device": a.device,
        "machine": machine,
        "ok": a.rc == "0" and ds is not None,
        "world": {"seed": int(a.seed), "scenes": int(a.scenes),
                  "keyframes_per_scene": int(a.keyframes_per_scene), "lean": True,
                  "splits": world_counts(index)},
        "preset": a.preset,
        "frame": (index or {}).get("frame_size"),
        "plan": plan_rec or None,
        "training": {"train_samples": plan_rec.get("size"), "iterations": iterations,
                     "validations": plan_rec.get("validations"), "batch_size": batch,
                     "images_seen_per_run": iterations * batch if iterations and batch else None,
                     "max_val_samples": (((ds or {}).get("options") or {}).get("max_val_samples")),
                     "test_samples": ((ds or {}).get("partition") or {}).get("test_samples")},
        "wall_seconds": {**walls, "total": int(time.time()) - int(a.t0)},
        "budget_s": int(a.budget),
        "runs": runs,
        "runs_from": runs_from,
        "arms": arms,
        "margin": margin_of(ds),
        "trend": (ds or {}).get("trend"),
        "checkpoint_for_bf16": best[0] if best else None,
        "mer": {"status": "not run",
                "why": "the third arm (late-sam-mer) needs `mer train` and `mer apply` on the "
                       "world first: no time is left for them within the step's budget"},
        "stages": stages,
    }
    tmp = a.out + ".tmp"
    with open(tmp, "w") as f:
        json.dump(rec, f, indent=2)
    os.replace(tmp, a.out)
    m = rec["margin"]
    head = f"science: {'dry run, ' if rec['dry_run'] else ''}{a.preset} on {a.device}: "
    if plan_rec:
        sp = rec["world"]["splits"]
        head += (f"world {sp['train']['keyframes']} / {sp['val']['keyframes']} / "
                 f"{sp['test']['keyframes']} keyframes (train / val / test), "
                 f"N = {plan_rec.get('size')}, {iterations} iterations per run, "
                 f"{plan_rec.get('mode')} ({rec['wall_seconds']['total']} s)")
    else:
        bad = next((s for s in stages if s["status"] != "ok"), None)
        head += ("stopped before the plan" + (f": stage {bad['stage']} {bad['status']}" if bad
                 else "") + f" ({rec['wall_seconds']['total']} s of a {a.budget} s budget)")
    lines = [head]
    for r in runs:
        lines.append(f"  {r['arm']:<9} seed {r['seed']}: test RMSE {r['test_rmse_m']:.3f} m"
                     if r["test_rmse_m"] is not None else f"  {r['arm']} seed {r['seed']}: -")
    if m["margin_m"]:
        lines.append(f"  margin late-sam over rgb: {m['margin_m']['mean']:+.3f} m "
                     f"({m['margin_pct']['mean']:+.1f} %), seed spread {m['seed_spread_m']}, "
                     f"{m['verdict']}")
    else:
        lines.append("  margin: not measured (see the stages)")
    lines.append("  stages: " + ", ".join(f"{s['stage']} {s['status']} {s['seconds']}s"
                                          for s in stages))
    print("\n".join(lines))
    return 0 if rec["ok"] else 1


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("plan")
    p.add_argument("--work", required=True)
    p.add_argument("--runs", type=int, required=True)
    p.add_argument("--batch", type=int, required=True)
    p.add_argument("--epochs", type=int, required=True)
    p.add_argument("--size", type=int, required=True)
    p.add_argument("--time-left", type=float, required=True)
    p.add_argument("--run-overhead", type=float, required=True)
    p.add_argument("--mode", choices=("auto", "parallel", "sequential"), default="auto")
    p.add_argument("--max-iterations", type=int, default=0, help="0: no cap")
    q = sub.add_parser("write")
    for k in ("work", "out", "dry", "device", "seed", "scenes", "keyframes-per-scene", "preset",
              "budget", "t0", "rc"):
        q.add_argument("--" + k, required=True)
    a = ap.parse_args()
    return plan(a) if a.cmd == "plan" else write(a)


if __name__ == "__main__":
    sys.exit(main())
