"""The Python module `depthsense` (crates/python; issue 42 item 5), run by `make test` after the
Rust tests (`make python` builds and installs the wheel first).

On the real nuScenes keyframe of ../shared/fixtures/nuscenes-kf0 and a tiny network with random
weights (depthsense_torch, randomised BatchNorm statistics so that the depth varies):

- the exported ONNX model in onnxruntime, fed `depthsense.inputs_from_raw`, gives the depth.png
  of `depthsense predict --image` on >= 99.99 % of the pixels (the same 16-bit value, so the
  same decoded SID bin); the same graph fed no radar does not (the comparison can fail);
- the inputs from the JPEG's bytes, from its path and from the prepared sample are one array;
- `read_sample` reads every file of the prepared sample as depthsense and an independent PNG
  decoder (PIL) read it; radar_points.bin rasterised in numpy from its documented layout gives
  the stored radar_raw.png;
- `score_sample` and `score` give the numbers of `depthsense eval --predictions`.

Binaries: $DEPTHSENSE_BIN (the `depthsense` beside its `depthsense-net`; `make test` sets it),
else target/debug, else target/release. A missing fixture is a counted skip
($DEPTHSENSE_SKIP_LOG, as crates/testkit counts them); a missing binary or torch fails under
`make test` ($DEPTHSENSE_BIN / DEPTHSENSE_REQUIRE_TORCH=1).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
KF0 = ROOT.parent / "shared" / "fixtures" / "nuscenes-kf0"
TOKEN = "ca9a282c9e77460f8360f564131a8af5"
# The keyframe's own sweep of RADAR_FRONT: the fixture holds no other radar file.
RADAR = ["--radar-sweeps", "1", "--radar-channels", "RADAR_FRONT"]

import depthsense  # noqa: E402  (the wheel `make python` installs into .venv)


def counted_skip(reason):
    """A skip recorded in make test's skip log (`test<TAB>reason`, as crates/testkit writes)."""
    log = os.environ.get("DEPTHSENSE_SKIP_LOG")
    if log:
        with open(log, "a") as f:
            f.write(f"python/tests/test_depthsense_py.py\t{reason}\n")
    pytest.skip(reason)


def binary():
    given = os.environ.get("DEPTHSENSE_BIN")
    if given:
        assert Path(given).is_file(), f"DEPTHSENSE_BIN={given}: no such file"
        return given
    for profile in ("debug", "release"):
        p = ROOT / "target" / profile / "depthsense"
        if p.is_file() and (p.parent / "depthsense-net").is_file():
            return str(p)
    counted_skip("no target/debug/depthsense or target/release/depthsense: cargo build first")


def run(*args):
    """`depthsense ARGS`, its stdout; a failure shows its stderr."""
    r = subprocess.run([binary(), *map(str, args)], capture_output=True, text=True)
    assert r.returncode == 0, f"depthsense {' '.join(map(str, args))}: {r.stderr}"
    return r.stdout


def png_values(d):
    """Depth in metres as `predict` stores it in depth.png: round(d x 256) (half away from 0),
    in [1, 65535]; 0 where there is no depth (depthsense_nuscenes::depth_png::encode_value)."""
    d = np.asarray(d, np.float64)
    ok = np.isfinite(d) & (d > 0)
    v = np.clip(np.floor(np.where(ok, d, 0) * 256 + 0.5), 1, 65535)
    return np.where(ok, v, 0).astype(np.int64)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    if not KF0.is_dir():
        counted_skip(f"fixture absent at {KF0}")
    try:
        import torch
        import onnxruntime  # noqa: F401
    except ImportError as e:
        if os.environ.get("DEPTHSENSE_REQUIRE_TORCH") == "1":
            raise
        counted_skip(f"no torch / onnxruntime in {sys.executable}: {e}")
    d = tmp_path_factory.mktemp("depthsense-py")
    jpeg = next((KF0 / "samples" / "CAM_FRONT").glob("*.jpg"))
    # A tiny network with random weights, saved as a state dict under depthsense's names.
    run("model-info", "--config", "tiny", "--json", d / "model.json")
    cfg = json.loads((d / "model.json").read_text())["config"]
    sys.path.insert(0, str(ROOT / "python"))
    import depthsense_torch as dt
    torch.manual_seed(0)
    net = dt.DepthSense(cfg).net
    with torch.no_grad():
        for name, v in net.state_dict().items():
            if name.endswith("running_var"):
                v.copy_(torch.rand_like(v) * 0.7 + 0.8)
            elif name.endswith("running_mean") or "attention" in name:
                v.copy_((torch.rand_like(v) - 0.5) * 0.2)
    torch.save(net.state_dict(), d / "tiny.pth")
    model = ["--checkpoint", d / "tiny.pth", "--config", "tiny"]
    run("export", *model, "--format", "onnx", "--out", d / "tiny.onnx")
    run("calibration", "--dataroot", KF0, "--version", "v1.0-mini", "--token", TOKEN, *RADAR,
        "--out", d / "calib.json")
    run("predict", *model, "--image", jpeg, "--calibration", d / "calib.json", "--device", "cpu",
        "--out", d / "pred")
    run("prepare", "--dataroot", KF0, "--version", "v1.0-mini", "--split", "all", *RADAR,
        "--out", d / "prepared")
    return {"dir": d, "jpeg": jpeg, "calib": d / "calib.json", "onnx": d / "tiny.onnx",
            "sidecar": d / "tiny.onnx.json", "sample": d / "prepared" / TOKEN}


def onnx_depth(w, inputs):
    import onnxruntime as ort
    sess = ort.InferenceSession(str(w["onnx"]), providers=["CPUExecutionProvider"])
    return sess.run(["depth"], inputs)[0][0, 0]


def test_onnx_on_the_modules_inputs_gives_predicts_depth(world):
    w = world
    inputs = depthsense.inputs_from_raw(w["jpeg"], w["calib"], sidecar=w["sidecar"])
    assert sorted(inputs) == ["image", "radar"]
    assert inputs["image"].shape == (1, 3, 350, 800) and inputs["image"].dtype == np.float32
    assert inputs["radar"].shape == (1, 1, 350, 800) and inputs["radar"].dtype == np.float32
    assert (inputs["radar"] > 0).sum() > 500, "the keyframe's radar strips are in the input"
    ref = png_values(depthsense.read_depth(w["dir"] / "pred" / "depth.png"))
    assert ref.shape == (350, 800) and len(np.unique(ref)) > 5, "the depth map varies"
    same = (png_values(onnx_depth(w, inputs)) == ref).mean()
    assert same >= 0.9999, f"ONNX on depthsense's inputs = predict on {same:.6%} of the pixels"
    # Control: the comparison sees a wrong input (here: no radar at all).
    blind = dict(inputs, radar=np.zeros_like(inputs["radar"]))
    same_blind = (png_values(onnx_depth(w, blind)) == ref).mean()
    assert same_blind < 0.9999, f"no radar still gave predict's depth on {same_blind:.6%}"


def test_inputs_from_bytes_path_and_prepared_sample_are_one_array(world):
    w = world
    from_path = depthsense.inputs_from_raw(str(w["jpeg"]), w["calib"], radar_input="height")
    from_bytes = depthsense.inputs_from_raw(w["jpeg"].read_bytes(), w["calib"],
                                            radar_input="height")
    prepared = depthsense.inputs_from_sample(w["sample"], radar_input="height")
    for k in ("image", "radar"):
        assert np.array_equal(from_path[k], from_bytes[k]), k
        assert np.array_equal(from_path[k], prepared[k]), k
    # The radar file named explicitly is the calibration's only file: the same input.
    pcd = next((KF0 / "samples" / "RADAR_FRONT").glob("*.pcd"))
    named = depthsense.inputs_from_raw(w["jpeg"], w["calib"], [pcd], radar_input="height")
    assert np.array_equal(named["radar"], from_path["radar"])
    # raw-height: 2 channels, raw first; RGB-only: no radar.
    two = depthsense.inputs_from_raw(w["jpeg"], w["calib"], radar_input="raw-height")
    assert two["radar"].shape == (1, 2, 350, 800)
    assert np.array_equal(two["radar"][:, 1:], from_path["radar"])
    assert "radar" not in depthsense.inputs_from_raw(w["jpeg"], w["calib"], radar_input="none")
    with pytest.raises(ValueError, match="radar_input"):
        depthsense.inputs_from_raw(w["jpeg"], w["calib"])
    with pytest.raises(ValueError, match="MER"):
        depthsense.inputs_from_raw(w["jpeg"], w["calib"], radar_input="mer")


def test_read_sample_reads_every_file(world):
    from PIL import Image
    w = world
    s = depthsense.read_sample(w["sample"])
    assert sorted(s) == ["image", "lidar_dense", "lidar_sparse", "lowheight_mask", "meta",
                         "radar_height", "radar_points", "radar_raw"]
    pil = lambda f: np.asarray(Image.open(w["sample"] / f))
    # Image: uint8 [350, 800, 3], the network's input x 255.
    assert s["image"].dtype == np.uint8 and s["image"].shape == (350, 800, 3)
    assert np.array_equal(s["image"], pil("image.png"))
    x = depthsense.inputs_from_sample(w["sample"], radar_input="height")
    assert np.array_equal(x["image"][0], s["image"].transpose(2, 0, 1) / np.float32(255))
    # Depth maps: float32 metres = the 16-bit value / 256.
    for k in ("lidar_sparse", "lidar_dense", "radar_raw", "radar_height"):
        assert s[k].dtype == np.float32 and s[k].shape == (350, 800), k
        assert np.array_equal(s[k], pil(f"{k}.png").astype(np.float32) / 256), k
    assert (s["lidar_sparse"] > 0).sum() > 1000
    assert np.array_equal(x["radar"][0, 0], s["radar_height"])
    # The low-height mask: 8-bit, 0 or 255; True where 255, only on lidar GT pixels.
    m = pil("lowheight_mask.png")
    assert m.dtype == np.uint8 and set(np.unique(m)) <= {0, 255}
    assert s["lowheight_mask"].dtype == np.bool_
    assert np.array_equal(s["lowheight_mask"], m == 255) and s["lowheight_mask"].any()
    assert not (s["lowheight_mask"] & (s["lidar_sparse"] == 0)).any()
    assert s["meta"]["sample_token"] == TOKEN and s["meta"]["conditions"] == ["day"]
    # radar_points.bin, rasterised here from its documented layout, is radar_raw.png.
    rp = s["radar_points"]
    assert rp["channels"] == ["RADAR_FRONT"] and rp["camera"]["width"] == 1600
    assert rp["groups"]["n_points"].sum() == len(rp["points"]) > 10
    assert rp["points"].dtype.names == ("channel", "sweep", "x", "y", "z")
    assert np.array_equal(s["radar_raw"], raster_raw(rp))
    again = depthsense.read_radar_points(w["sample"] / "radar_points.bin")
    assert np.array_equal(again["points"], rp["points"])


def raster_raw(rp):
    """The raw radar map (SPEC §5) of radar_points.bin in numpy, float32 arithmetic as
    depthsense's: project at full resolution (u, v strictly inside a 1-pixel border, z > 1 m),
    frame pixel (floor(u/2), floor(v/2) - 100), the nearest return per pixel, stored x 256."""
    c, p = rp["camera"], rp["points"]
    f32 = np.float32
    x, y, z = p["x"], p["y"], p["z"]
    ok = z > f32(1.0)
    z = np.where(ok, z, f32(1.0))
    u = f32(c["fx"]) * x / z + f32(c["cx"])
    v = f32(c["fy"]) * y / z + f32(c["cy"])
    ok &= (u > 1) & (u < c["width"] - 1) & (v > 1) & (v < c["height"] - 1)
    col = np.floor(u * f32(0.5)).astype(np.int64)
    row = np.floor(v * f32(0.5)).astype(np.int64) - 100
    ok &= (col >= 0) & (col < 800) & (row >= 0) & (row < 350)
    out = np.zeros((350, 800), np.float32)
    for r, cc, d in sorted(zip(row[ok], col[ok], z[ok]), key=lambda t: -t[2]):
        out[r, cc] = d  # nearest last: nearest wins
    return (png_values(out) / 256).astype(np.float32)


def test_scores_are_eval_predictions_numbers(world):
    w = world
    depth = onnx_depth(w, depthsense.inputs_from_sample(w["sample"], sidecar=w["sidecar"]))
    preds = w["dir"] / "preds"
    preds.mkdir()
    np.save(preds / f"{TOKEN}.npy", depth.astype(np.float32))
    run("eval", "--predictions", preds, "--data", w["dir"] / "prepared", "--split", "all",
        "--out", w["dir"] / "eval")
    tables = json.loads((w["dir"] / "eval" / "tables.json").read_text())
    want = tables["models"][0]["report"]
    got = depthsense.score_sample(depth, w["sample"])
    assert got["rows"] == want["rows"] and got["images_seen"] == 1
    assert got["headline"]["cap_m"] == 80 and got["headline"]["n_pixels"] > 1000
    assert got["headline"]["metrics"]["rmse"] > 0
    # score() on the arrays read_sample gives, with the sample's conditions: the same numbers.
    s = depthsense.read_sample(w["sample"])
    arrays = depthsense.score(depth, s["lidar_sparse"], s["lowheight_mask"],
                              s["meta"]["conditions"])
    assert arrays["rows"] == want["rows"]
    # Another protocol changes them (the numbers are computed, not copied).
    clamp = depthsense.score_sample(depth, w["sample"], protocol="clamp")
    assert clamp["rows"] != want["rows"]
