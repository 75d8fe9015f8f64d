#!/usr/bin/env python3
"""Format check of a nuScenes-style dataroot with the official nuScenes devkit.

Loads the tables with `NuScenes(version, dataroot)` and, for several keyframes, projects the
LIDAR_TOP sweep and every radar channel into CAM_FRONT with
`NuScenesExplorer.map_pointcloud_to_image`; asserts that lidar points land in the image, that
radar files parse with and without the default filters, that prev/next chains are consistent
and that every referenced file exists. Prints a JSON summary; exits non-zero on any failure.

Usage: scripts/devkit_check.py --dataroot D --version v1.0-synth [--samples 6]
Exit code 3 means the devkit is not installed (`pip install nuscenes-devkit`).
"""
import argparse
import json
import os
import sys


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataroot", required=True, help="dataroot holding <version>/, samples/, sweeps/, maps/")
    ap.add_argument("--version", default="v1.0-synth", help="version folder name")
    ap.add_argument("--samples", type=int, default=6, help="keyframes to project (spread over all scenes)")
    args = ap.parse_args()
    try:
        import numpy as np
        from nuscenes.nuscenes import NuScenes
        from nuscenes.utils.data_classes import RadarPointCloud
    except ImportError as e:  # pragma: no cover
        print(f"nuscenes-devkit not importable: {e}", file=sys.stderr)
        return 3

    nusc = NuScenes(version=args.version, dataroot=args.dataroot, verbose=False)
    failures = []

    def check(cond, msg):
        if not cond:
            failures.append(msg)

    # Every table the devkit loads is non-empty where it must be.
    for t in ["category", "attribute", "visibility", "sensor", "calibrated_sensor", "ego_pose",
              "log", "scene", "sample", "sample_data", "map"]:
        check(len(getattr(nusc, t)) > 0, f"table {t} is empty")
    # Tokens are 32 lower-case hex digits (visibility uses "1".."4" as nuScenes does).
    for t in ["scene", "sample", "sample_data", "ego_pose", "calibrated_sensor", "sensor", "log",
              "instance", "sample_annotation", "category", "attribute", "map"]:
        for r in getattr(nusc, t):
            tok = r["token"]
            if not (len(tok) == 32 and all(c in "0123456789abcdef" for c in tok)):
                failures.append(f"{t} token {tok!r} is not 32 hex digits")
                break
    # prev/next chains are symmetric; files exist.
    sd_by_tok = {r["token"]: r for r in nusc.sample_data}
    for r in nusc.sample_data:
        if r["next"]:
            check(sd_by_tok[r["next"]]["prev"] == r["token"], f"sample_data chain broken at {r['token']}")
        check(os.path.exists(os.path.join(args.dataroot, r["filename"])), f"missing file {r['filename']}")
    for r in nusc.sample:
        if r["next"]:
            check(nusc.get("sample", r["next"])["prev"] == r["token"], f"sample chain broken at {r['token']}")
    for s in nusc.scene:
        n, tok = 0, s["first_sample_token"]
        while tok:
            n += 1
            last = tok
            tok = nusc.get("sample", tok)["next"]
        check(n == s["nbr_samples"], f"scene {s['name']}: {n} samples, nbr_samples {s['nbr_samples']}")
        check(last == s["last_sample_token"], f"scene {s['name']}: last sample mismatch")
    for inst in nusc.instance:
        n, tok = 0, inst["first_annotation_token"]
        while tok:
            n += 1
            tok = nusc.get("sample_annotation", tok)["next"]
        check(n == inst["nbr_annotations"], f"instance {inst['token']}: chain of {n}")

    # Projection of lidar and radar into CAM_FRONT for keyframes spread over the dataset.
    samples = nusc.sample
    k = max(1, min(args.samples, len(samples)))
    picks = [samples[int(i * (len(samples) - 1) / max(1, k - 1))] for i in range(k)] if k > 1 else samples[:1]
    radar_channels = [c for c in ["RADAR_FRONT", "RADAR_FRONT_LEFT", "RADAR_FRONT_RIGHT"]]
    summary = {"samples": [], "lidar_points_in_image": 0, "radar_points_in_image": 0}
    for s in picks:
        cam = s["data"].get("CAM_FRONT")
        check(cam is not None, f"sample {s['token']} has no CAM_FRONT")
        if cam is None:
            continue
        row = {"sample": s["token"]}
        pts, depth, im = nusc.explorer.map_pointcloud_to_image(s["data"]["LIDAR_TOP"], cam)
        check(im.size == (1600, 900), f"CAM_FRONT image size {im.size}")
        check(pts.shape[1] > 1000, f"only {pts.shape[1]} lidar points project into the image of {s['token']}")
        check(bool(np.all(depth > 1.0)), "lidar depths <= 1 m after min_dist filtering")
        row["lidar_in_image"] = int(pts.shape[1])
        row["lidar_median_depth_m"] = float(np.median(depth)) if depth.size else None
        summary["lidar_points_in_image"] += int(pts.shape[1])
        for ch in radar_channels:
            tok = s["data"].get(ch)
            check(tok is not None, f"sample {s['token']} has no {ch}")
            if tok is None:
                continue
            pts, depth, _ = nusc.explorer.map_pointcloud_to_image(tok, cam)
            row[ch.lower() + "_in_image"] = int(pts.shape[1])
            summary["radar_points_in_image"] += int(pts.shape[1])
            path = nusc.get_sample_data_path(tok)
            all_pts = RadarPointCloud.from_file(path, invalid_states=list(range(18)),
                                                dynprop_states=list(range(8)), ambig_states=list(range(5)))
            filt = RadarPointCloud.from_file(path)
            check(0 < all_pts.nbr_points() <= 125, f"{ch}: {all_pts.nbr_points()} points")
            check(filt.nbr_points() <= all_pts.nbr_points(), f"{ch}: filters added points")
            check(bool(np.all(all_pts.points[2] == 0.0)), f"{ch}: radar z is not 0 in the sensor frame")
            row[ch.lower() + "_filtered_of_all"] = [int(filt.nbr_points()), int(all_pts.nbr_points())]
        summary["samples"].append(row)
    check(summary["radar_points_in_image"] > 0, "no radar point projects into any image")
    summary["tables"] = {t: len(getattr(nusc, t)) for t in nusc.table_names}
    summary["failures"] = failures
    print(json.dumps(summary, indent=1))
    if failures:
        print(f"FAILED: {len(failures)} check(s)", file=sys.stderr)
        return 1
    print("devkit check OK", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
