"""Runs exported depthsense models outside depthsense (crates/export/tests/export.rs):

    python run_exported.py JOBS.json

JOBS.json is a list of {"format": onnx|torchscript|pytorch, "model": FILE, "dir": DIR,
"shape": [N, C, H, W]}. Each job reads DIR/image.f32 [N,3,H,W] and, when C > 0, DIR/radar.f32
[N,C,H,W] (little-endian float32), runs FILE in onnxruntime (CPU), torch.jit.load or
python/depthsense_torch.py, and writes DIR/depth.f32. One process for many jobs: torch and
onnxruntime are imported once. Exit code 77: a package is missing."""

import json
import os
import sys

try:
    import numpy as np
    import torch
    import onnxruntime as ort
except ImportError as e:
    print(e, file=sys.stderr)
    sys.exit(77)

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "../../../python"))
import depthsense_torch as dt  # noqa: E402

torch.set_num_threads(1)


def run(fmt, model, d, n, c, h, w):
    image = np.fromfile(os.path.join(d, "image.f32"), dtype="<f4").reshape(n, 3, h, w)
    radar = np.fromfile(os.path.join(d, "radar.f32"), dtype="<f4").reshape(n, c, h, w) if c else None
    if fmt == "onnx":
        so = ort.SessionOptions()
        so.intra_op_num_threads = 1
        s = ort.InferenceSession(model, so, providers=["CPUExecutionProvider"])
        feeds = {"image": image} if radar is None else {"image": image, "radar": radar}
        names = [i.name for i in s.get_inputs()]
        assert names == list(feeds), names
        return s.run(["depth"], feeds)[0]
    if fmt == "torchscript":
        m = torch.jit.load(model)
    else:
        saved = torch.load(model)
        m = dt.DepthSense(saved["config"])
        m.net.load_state_dict(saved["state_dict"])
        m.eval()
    args = [torch.from_numpy(image)] + ([torch.from_numpy(radar)] if radar is not None else [])
    with torch.no_grad():
        return m(*args).numpy()


with open(sys.argv[1]) as f:
    jobs = json.load(f)
for j in jobs:
    depth = run(j["format"], j["model"], j["dir"], *j["shape"])
    depth.astype("<f4").tofile(os.path.join(j["dir"], "depth.f32"))
