#!/usr/bin/env python3
"""How much could radar fusion gain, at most, if it only fixed the pixels near radar returns?

Reads a prepared folder (`depthsense prepare`) and two folders of predictions written by
`depthsense predict --split test --format npy` (RGB-only and fusion, one `<token>.npy` per
sample, metres, 800x350 training frame). Scores both with `eval`'s default protocol (GT =
`lidar_sparse.png`, pixels with 0 < GT <= 80 m, RMSE per image then the mean; docs/guide/evaluate.md)
and then the *oracle* RGB-only prediction whose error is set to zero on the pixels covered by
the height-extended radar map (`radar_height.png`, SPEC §5), and on that strip dilated by k px.
The oracle rows bound what a model gains by being exact where radar points are (k = 0) or
within k px of them; they are an analysis, not a method. Then, by distance to the nearest strip
pixel (rings), both models' RMSE pooled over the ring's pixels, and on the strip pixels the
RMSE of the radar depth itself.

    python3 scripts/radar_oracle.py PREPARED PRED_RGB PRED_FUSION [--cap 80] [--dilate 0,4,16,32]

Needs numpy, pillow and scipy (the project's .venv has them).
"""
import argparse
import os
import sys

import numpy as np
from PIL import Image
from scipy.ndimage import binary_dilation, distance_transform_edt


def depth_png(path):
    """A 16-bit depth PNG (depth x 256, 0 = none) in metres."""
    return np.asarray(Image.open(path)).astype(np.float64) / 256.0


def rmse(sq_err, valid):
    return float(np.sqrt(sq_err[valid].mean()))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("prepared")
    ap.add_argument("pred_rgb")
    ap.add_argument("pred_fusion")
    ap.add_argument("--cap", type=float, default=80.0, help="depth cap in metres (default 80)")
    ap.add_argument("--dilate", default="0,4,16,32", help="strip dilations in px (default 0,4,16,32)")
    a = ap.parse_args()
    dilations = [int(k) for k in a.dilate.split(",")]
    tokens = sorted(f[:-4] for f in os.listdir(a.pred_rgb) if f.endswith(".npy"))
    if not tokens:
        sys.exit(f"{a.pred_rgb}: no <token>.npy predictions")
    rows = {"rgb": [], "fusion": []}
    rows.update({f"oracle rgb, strip+{k} px": [] for k in dilations})
    covered = []
    ring_edges = [0, 1, 5, 17, 33, 65, np.inf]
    # per ring: [pixels, rgb squared error, fusion squared error]
    rings = np.zeros((len(ring_edges) - 1, 3))
    radar_self = np.zeros(3)  # strip pixels with GT: count, squared error, within 10 %
    for t in tokens:
        fus_path = os.path.join(a.pred_fusion, t + ".npy")
        if not os.path.exists(fus_path):
            sys.exit(f"{fus_path}: missing (both folders must hold the same samples)")
        gt = depth_png(os.path.join(a.prepared, t, "lidar_sparse.png"))
        radar_m = depth_png(os.path.join(a.prepared, t, "radar_height.png"))
        strip = radar_m > 0
        rgb = np.load(os.path.join(a.pred_rgb, t + ".npy")).squeeze().astype(np.float64)
        fus = np.load(fus_path).squeeze().astype(np.float64)
        if rgb.shape != gt.shape or fus.shape != gt.shape:
            sys.exit(f"{t}: prediction {rgb.shape}/{fus.shape} vs GT {gt.shape}")
        valid = (gt > 0) & (gt <= a.cap)
        if not valid.any():
            continue
        sq_rgb = (rgb - gt) ** 2
        sq_fus = (fus - gt) ** 2
        rows["rgb"].append(rmse(sq_rgb, valid))
        rows["fusion"].append(rmse(sq_fus, valid))
        covered.append((strip & valid).sum() / valid.sum())
        for k in dilations:
            m = binary_dilation(strip, iterations=k) if k > 0 else strip
            rows[f"oracle rgb, strip+{k} px"].append(rmse(np.where(m, 0.0, sq_rgb), valid))
        dist_px = distance_transform_edt(~strip)
        for i in range(len(ring_edges) - 1):
            m = valid & (dist_px >= ring_edges[i]) & (dist_px < ring_edges[i + 1])
            rings[i] += [m.sum(), sq_rgb[m].sum(), sq_fus[m].sum()]
        m = valid & strip
        err = np.abs(radar_m - gt)[m]
        radar_self += [m.sum(), (err**2).sum(), (err < 0.1 * gt[m]).sum()]
    base = np.mean(rows["rgb"])
    print(f"{len(rows['rgb'])} images, cap {a.cap:g} m; GT pixels on the radar strip: "
          f"{100 * np.mean(covered):.1f} % (mean per image)")
    print(f"{'prediction':28s} {'RMSE (m)':>9s} {'vs rgb':>8s}")
    for name, v in rows.items():
        print(f"{name:28s} {np.mean(v):9.3f} {100 * (np.mean(v) / base - 1):+7.1f} %")
    n, sq, good = radar_self
    if n > 0:
        print(f"strip pixels with GT: {int(n)}; the radar depth itself: RMSE {np.sqrt(sq / n):.2f} m, "
              f"{100 * good / n:.1f} % within 10 % of the GT")
    print("rings by distance to the nearest strip pixel (pooled over pixels):")
    total_sq = rings[:, 1].sum()
    for i, (n, sr, sf) in enumerate(rings):
        if n == 0:
            continue
        lo, hi = ring_edges[i], ring_edges[i + 1]
        print(f"  [{lo:g}, {hi:g}) px: {100 * n / rings[:, 0].sum():5.1f} % of GT px, "
              f"RMSE rgb {np.sqrt(sr / n):6.2f} m, fusion {np.sqrt(sf / n):6.2f} m "
              f"({100 * (np.sqrt(sf / sr) - 1):+.1f} %), share of rgb's squared error "
              f"{100 * sr / total_sq:.1f} %")


if __name__ == "__main__":
    main()
