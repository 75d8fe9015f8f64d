#!/usr/bin/env python3
"""onnxruntime latency of an exported depthsense graph (gpu-check's `ort_cuda` step, issue 45).

  ort_latency.py --onnx MODEL.onnx --device cuda|cpu --batch B --height H --width W --out FILE

On `cuda` the CUDA execution provider is asked for; when this onnxruntime does not have it the
JSON says so (`"cuda_provider": false`) and nothing is timed. Random inputs of the graph's own
input shapes (dynamic axes: batch B, the graph's fixed H×W), 3 warm-up runs, the median of 20.
"""
import argparse
import json
import os
import statistics
import sys
import time


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--onnx", required=True)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--batch", type=int, default=3)
    ap.add_argument("--height", type=int, default=350)
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    rec = {"onnx": os.path.basename(a.onnx), "device": a.device, "batch": a.batch}
    try:
        import numpy as np
        import onnxruntime as ort
    except ImportError as e:
        rec.update({"error": f"not importable: {e}"})
        return write(a.out, rec, 1)
    avail = ort.get_available_providers()
    rec.update({"onnxruntime": ort.__version__, "available_providers": avail,
                "cuda_provider": "CUDAExecutionProvider" in avail})
    if a.device.startswith("cuda"):
        if not rec["cuda_provider"]:
            rec["note"] = "this onnxruntime has no CUDA execution provider: not timed"
            return write(a.out, rec, 0)
        providers = ["CUDAExecutionProvider", "CPUExecutionProvider"]
    else:
        providers = ["CPUExecutionProvider"]
    sess = ort.InferenceSession(a.onnx, providers=providers)
    rec["providers_used"] = sess.get_providers()
    feeds = {}
    for i in sess.get_inputs():
        free = {0: a.batch, 2: a.height, 3: a.width}
        shape = [d if isinstance(d, int) else free.get(k, 1) for k, d in enumerate(i.shape)]
        feeds[i.name] = np.random.default_rng(0).random(shape, dtype=np.float32)
        rec.setdefault("inputs", {})[i.name] = shape
    for _ in range(a.warmup):
        sess.run(None, feeds)
    times = []
    for _ in range(a.repeats):
        t = time.perf_counter()
        sess.run(None, feeds)
        times.append((time.perf_counter() - t) * 1e3)
    rec.update({"median_ms": statistics.median(times), "min_ms": min(times),
                "repeats": a.repeats, "warmup": a.warmup})
    print(f"onnxruntime {rec['providers_used'][0]}: {rec['median_ms']:.2f} ms median, batch {a.batch}")
    return write(a.out, rec, 0)


def write(path, rec, rc):
    with open(path + ".tmp", "w") as f:
        json.dump(rec, f, indent=2)
    os.replace(path + ".tmp", path)
    return rc


if __name__ == "__main__":
    sys.exit(main())
