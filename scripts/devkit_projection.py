#!/usr/bin/env python3
"""The official nuScenes devkit's projection of keyframes, in depthsense's training frame.

An independent golden for `depthsense prepare` (issue 23): nothing here comes from depthsense's
code. For each keyframe TOKEN it writes into OUT/TOKEN/, as 350x800 little-endian float32 files
(0 = no point):

  lidar_sparse.f32   LIDAR_TOP keyframe sweep into CAM_FRONT with
                     `NuScenesExplorer.map_pointcloud_to_image` (depth > 1 m, 1 < u < W-1,
                     1 < v < H-1: SPEC §2)
  radar_raw.f32      every radar channel of --radar-channels: one sweep with the same devkit
                     function; N > 1 sweeps with `RadarPointCloud.from_file_multisweep(...,
                     ref_chan='CAM_FRONT', nsweeps=N)` (each sweep through its own ego pose),
                     then `view_points` and the same mask

A dataroot whose tables are partial (the real keyframe fixture has no category, instance, map …
tables) is read through a temporary shadow dataroot that links every file and adds the missing
tables as empty lists (map: one placeholder holding every log); the summary names them.

Each full-resolution point (u, v) lands at training-frame pixel (floor(u/2), floor(v/2) - 100)
(SPEC §3); rows above the crop are dropped; where several points share a pixel the nearest wins
(SPEC §4, §5). Beside each raster, NAME.edge.u8 (350x800 bytes) marks with 1 the pixels on
either side of a pixel edge that a point lies within EDGE_PX of: float32 rounding may put such a
point on either side, so only there may another projection differ. It prints a JSON summary with,
per keyframe, the devkit's own counts for the LIDAR_TOP scan: points read and `remove_close(1.0)`
removals.

Usage: scripts/devkit_projection.py --dataroot D --version V --sample TOKEN[,TOKEN…] --out DIR
         [--radar-sweeps N] [--radar-channels A,B] [--no-radar-filters]
Exit code 3 means the devkit is not installed (`make setup` installs it).
"""
import argparse
import json
import os
import sys

W_FULL, H_FULL = 1600, 900
W, H = 800, 350
CROP_TOP = 100


# A full-resolution coordinate this close to a pixel edge (in full-resolution pixels) may land on
# either side under float32 rounding: the devkit moves float32 points in four rounded steps,
# depthsense in one composed float32 transform; a few 1e-6 m of difference is ~1e-3 px at 5 m
# (measured: 1.2e-3 px on the synthetic world). A hundredth of a pixel leaves a margin.
EDGE_PX = 1e-2


def to_frame(u, v, depth):
    """Nearest-wins raster of full-resolution points in the 800x350 training frame (SPEC §3), the
    number of points in the frame, and the edge mask: 1 on the pixel of every point within
    EDGE_PX of a pixel edge and on the pixel across that edge."""
    import numpy as np

    u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    x = np.floor(u / 2.0).astype(np.int64)
    y = np.floor(v / 2.0).astype(np.int64) - CROP_TOP
    keep = (y >= 0) & (y < H) & (x >= 0) & (x < W)
    out = np.full((H, W), np.inf)
    np.minimum.at(out, (y[keep], x[keep]), np.asarray(depth, dtype=np.float64)[keep])
    out[np.isinf(out)] = 0.0
    edge = np.zeros((H, W), dtype=np.uint8)
    near_u = np.abs(u / 2.0 - np.round(u / 2.0)) < EDGE_PX / 2
    near_v = np.abs(v / 2.0 - np.round(v / 2.0)) < EDGE_PX / 2
    # Across the edge e = round(a) lie the pixels e - 1 and e: the other one is 2e - 1 - own.
    xa = np.round(u / 2.0).astype(np.int64) * 2 - 1 - x
    ya = np.round(v / 2.0).astype(np.int64) * 2 - 1 - (y + CROP_TOP) - CROP_TOP
    for xs, ys, m in [(x, y, near_u | near_v), (xa, y, near_u), (x, ya, near_v), (xa, ya, near_u & near_v)]:
        ok = m & (ys >= 0) & (ys < H) & (xs >= 0) & (xs < W)
        edge[ys[ok], xs[ok]] = 1
    return out.astype(np.float32), int(keep.sum()), edge


def devkit_mask(u, v, depth):
    """`map_pointcloud_to_image`'s own filter (min_dist = 1.0)."""
    m = depth > 1.0
    m &= u > 1
    m &= u < W_FULL - 1
    m &= v > 1
    m &= v < H_FULL - 1
    return m


DEVKIT_TABLES = ["category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor",
                 "ego_pose", "log", "scene", "sample", "sample_data", "sample_annotation", "map"]


def shadow_dataroot(dataroot, version):
    """(dataroot the devkit can load, tables added empty); a temporary shadow when tables miss."""
    import tempfile

    tables = os.path.join(dataroot, version)
    missing = [t for t in DEVKIT_TABLES if not os.path.exists(os.path.join(tables, t + ".json"))]
    if not missing:
        return dataroot, []
    shadow = tempfile.mkdtemp(prefix="devkit-shadow-")
    for name in os.listdir(dataroot):
        if name != version:
            os.symlink(os.path.abspath(os.path.join(dataroot, name)), os.path.join(shadow, name))
    os.makedirs(os.path.join(shadow, version))
    for name in os.listdir(tables):
        os.symlink(os.path.abspath(os.path.join(tables, name)), os.path.join(shadow, version, name))
    for t in missing:
        rows = []
        if t == "map":  # the devkit indexes logs by map: one placeholder map holding every log
            with open(os.path.join(tables, "log.json")) as f:
                logs = [r["token"] for r in json.load(f)]
            rows = [{"token": "0" * 32, "log_tokens": logs, "category": "", "filename": ""}]
        with open(os.path.join(shadow, version, t + ".json"), "w") as f:
            json.dump(rows, f)
    return shadow, missing


def write(out, name, raster_edge):
    raster, edge = raster_edge
    raster.tofile(os.path.join(out, name + ".f32"))
    edge.tofile(os.path.join(out, name + ".edge.u8"))


def project_sample(nusc, token, channels, radar_sweeps, out):
    """Writes OUT/{lidar_sparse,radar_raw}.{f32,edge.u8} for keyframe TOKEN; returns its counts."""
    import numpy as np
    from nuscenes.utils.data_classes import LidarPointCloud, RadarPointCloud
    from nuscenes.utils.geometry_utils import view_points

    sample = nusc.get("sample", token)
    cam = sample["data"]["CAM_FRONT"]
    cam_sd = nusc.get("sample_data", cam)
    intrinsic = np.array(nusc.get("calibrated_sensor", cam_sd["calibrated_sensor_token"])["camera_intrinsic"])
    row = {"sample": token}

    # LIDAR_TOP: the devkit's counts, then its projection.
    lidar = sample["data"]["LIDAR_TOP"]
    pc = LidarPointCloud.from_file(nusc.get_sample_data_path(lidar))
    n_read = pc.nbr_points()
    pc.remove_close(1.0)
    row["lidar_points"] = n_read
    row["lidar_remove_close_1m"] = n_read - pc.nbr_points()
    pts, depth, _ = nusc.explorer.map_pointcloud_to_image(lidar, cam)
    raster, n, edge = to_frame(pts[0], pts[1], depth)
    write(out, "lidar_sparse", (raster, edge))
    row["lidar_in_image"] = int(pts.shape[1])
    row["lidar_in_frame"] = n
    row["lidar_near_edge"] = int(edge.sum())

    # Radar: every channel, nearest wins over all of them.
    us, vs, ds = [np.zeros(0)], [np.zeros(0)], [np.zeros(0)]
    row["radar_channels_present"] = []
    for ch in channels:
        tok = sample["data"].get(ch)
        if tok is None:
            continue
        row["radar_channels_present"].append(ch)
        if radar_sweeps <= 1:
            p, d, _ = nusc.explorer.map_pointcloud_to_image(tok, cam)
            m = np.ones(len(d), dtype=bool)
        else:
            rpc, _ = RadarPointCloud.from_file_multisweep(nusc, sample, ch, "CAM_FRONT", nsweeps=radar_sweeps)
            d = rpc.points[2, :]
            p = view_points(rpc.points[:3, :], intrinsic, normalize=True)
            m = devkit_mask(p[0], p[1], d)
        us.append(p[0][m])
        vs.append(p[1][m])
        ds.append(d[m])
    raster, n, edge = to_frame(np.concatenate(us), np.concatenate(vs), np.concatenate(ds))
    write(out, "radar_raw", (raster, edge))
    row["radar_in_image"] = int(sum(len(d) for d in ds))
    row["radar_in_frame"] = n
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataroot", required=True, help="nuScenes dataroot")
    ap.add_argument("--version", required=True, help="version folder, e.g. v1.0-mini")
    ap.add_argument("--sample", required=True, help="keyframe (sample) tokens, comma-separated")
    ap.add_argument("--out", required=True, help="folder for OUT/<token>/*.f32 and *.edge.u8")
    ap.add_argument("--radar-sweeps", type=int, default=1, help="sweeps per radar channel")
    ap.add_argument("--radar-channels", default="RADAR_FRONT,RADAR_FRONT_LEFT,RADAR_FRONT_RIGHT",
                    help="comma-separated radar channels")
    ap.add_argument("--no-radar-filters", action="store_true",
                    help="keep every radar point (RadarPointCloud.disable_filters())")
    args = ap.parse_args()
    try:
        from nuscenes.nuscenes import NuScenes
        from nuscenes.utils.data_classes import RadarPointCloud
    except ImportError as e:  # pragma: no cover
        print(f"nuscenes-devkit not importable: {e}", file=sys.stderr)
        return 3

    if args.no_radar_filters:
        RadarPointCloud.disable_filters()
    else:
        RadarPointCloud.default_filters()
    dataroot, added = shadow_dataroot(args.dataroot, args.version)
    nusc = NuScenes(version=args.version, dataroot=dataroot, verbose=False)
    channels = [c for c in args.radar_channels.split(",") if c]
    summary = {"tables_added_empty": added, "edge_px": EDGE_PX, "samples": []}
    for token in args.sample.split(","):
        out = os.path.join(args.out, token)
        os.makedirs(out, exist_ok=True)
        summary["samples"].append(project_sample(nusc, token, channels, args.radar_sweeps, out))
    print(json.dumps(summary))
    if dataroot != args.dataroot:
        import shutil

        shutil.rmtree(dataroot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
