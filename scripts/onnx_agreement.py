#!/usr/bin/env python3
"""How closely an exported ONNX model reproduces `depthsense predict` on prepared samples.

    depthsense predict --checkpoint RUN/best.safetensors --data PREPARED --split test \
        --format npy --out PREDS
    depthsense export --checkpoint RUN/best.safetensors --format onnx --out model.onnx
    .venv/bin/python scripts/onnx_agreement.py --onnx model.onnx --data PREPARED --preds PREDS

For every `PREDS/<token>.npy` (float32 metres, what `predict` wrote) the sample folder
`PREPARED/<token>/` is fed to onnxruntime (CPU) as the sidecar `model.onnx.json` says: the image
in [0, 1] and the radar input the network was trained on (height-extended, raw, or both; MER
inputs are not handled here). Prints one JSON object: pixels compared, the fraction identical,
within 1 mm, and the largest difference in metres and in SID bins (ordinal models).
"""

import argparse
import json
import math
import os
import sys

import numpy as np
import onnxruntime as ort
from PIL import Image


def sid_bin(depth_m, sid):
    """The SID bin of a depth (SPEC §7): thresholds alpha * (beta / alpha) ** (i / K)."""
    a, b, k = sid["alpha_m"], sid["beta_m"], sid["bins"]
    d = np.clip(depth_m + sid.get("decode_offset_m", 0.0), a, b)
    return np.floor(k * np.log(d / a) / math.log(b / a)).astype(np.int64)


def depth_png(path):
    return np.asarray(Image.open(path), np.float32) / 256.0


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--onnx", required=True)
    p.add_argument("--data", required=True, help="the prepared folder")
    p.add_argument("--preds", required=True, help="predict --data ... --format npy output")
    p.add_argument("--threads", type=int, default=0)
    a = p.parse_args()
    side = json.load(open(a.onnx + ".json"))
    radar = side.get("radar_input")
    if radar == "mer":
        sys.exit("MER inputs are not handled by this script")
    so = ort.SessionOptions()
    if a.threads:
        so.intra_op_num_threads = a.threads
    sess = ort.InferenceSession(a.onnx, so, providers=["CPUExecutionProvider"])
    names = sorted(f[:-4] for f in os.listdir(a.preds) if f.endswith(".npy"))
    if not names:
        sys.exit(f"{a.preds}: no <token>.npy (run `depthsense predict --data ... --format npy`)")
    n = same = mm = 0
    max_m = 0.0
    max_bins = 0
    images_differing = 0
    for t in names:
        s = os.path.join(a.data, t)
        image = np.asarray(Image.open(f"{s}/image.png").convert("RGB"), np.float32)
        feeds = {"image": image.transpose(2, 0, 1)[None] / 255.0}
        if radar is not None:
            planes = {
                "height": ["radar_height.png"],
                "raw": ["radar_raw.png"],
                "raw-height": ["radar_raw.png", "radar_height.png"],
            }[radar]
            feeds["radar"] = np.stack([depth_png(f"{s}/{f}") for f in planes])[None]
        onnx = sess.run(["depth"], feeds)[0][0, 0]
        ours = np.load(os.path.join(a.preds, t + ".npy")).reshape(onnx.shape)
        d = np.abs(onnx.astype(np.float64) - ours)
        n += d.size
        same += int((d == 0).sum())
        mm += int((d <= 1e-3).sum())
        images_differing += int((d > 1e-3).any())
        max_m = max(max_m, float(d.max()))
        if side["model_config"]["head"] == "ordinal":
            bins = np.abs(sid_bin(onnx, side["sid"]) - sid_bin(ours, side["sid"]))
            max_bins = max(max_bins, int(bins.max()))
    print(json.dumps({
        "images": len(names),
        "pixels": n,
        "frac_identical": same / n,
        "frac_within_1mm": mm / n,
        "pixels_beyond_1mm": n - mm,
        "images_with_a_pixel_beyond_1mm": images_differing,
        "max_abs_diff_m": max_m,
        "max_sid_bins_apart": max_bins,
        "onnxruntime": ort.__version__,
    }, indent=1))


if __name__ == "__main__":
    main()
