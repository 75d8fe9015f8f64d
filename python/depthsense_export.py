#!/usr/bin/env python3
"""The conversion step of `depthsense export` (crates/export): a depthsense network as ONNX,
TorchScript or a PyTorch state dict, through `depthsense_torch.DepthSense` (the same module
PyTorch users fine-tune, checked against depthsense by crates/checkpoint/tests/model/torch_reference_params.rs
and crates/export/tests/export.rs).

    python depthsense_export.py --weights W.safetensors --config CONFIG.json \
        --format onnx|torchscript|pytorch --out FILE [--format F2 --out FILE2 …]
        [--batch N|dynamic] [--precision fp32|fp16]

`depthsense export` writes W and CONFIG (the loaded network's variables under depthsense's
names and its model config), runs this script with a temporary FILE and renames it when this
exits 0. The graph's contract (docs/guide/deploy.md): inputs `image` float32
[N,3,H,W] RGB in [0, 1] and `radar` float32 [N,C,H,W] in metres (absent for RGB-only networks),
output `depth` float32 [N,1,out_height,out_width] in metres; with `--precision fp16` the
network computes in half precision between float32 inputs and output.

Route: ONNX by torch.onnx's TorchScript-based exporter (opset 17) from a trace of the module —
the ops are those PyTorch runs, and the same trace is the TorchScript file. Exit codes: 0 done,
2 bad input (message on stderr), 77 torch (or onnx for its check) not importable.
"""

import argparse
import json
import os
import sys
import warnings

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

try:
    import torch
    import torch.nn as nn
except ImportError as e:
    print(f"torch is not importable by {sys.executable}: {e}", file=sys.stderr)
    sys.exit(77)

import depthsense_torch as dt  # noqa: E402

OPSET = 17


class Graph(nn.Module):
    """The exported graph: `DepthSense` with float32 inputs and output whatever the precision;
    RGB-only networks take the image alone."""

    def __init__(self, model, half):
        super().__init__()
        self.model = model.half() if half else model
        self.half = half

    def run(self, image, radar):
        if self.half:
            image = image.half()
            radar = radar.half() if radar is not None else None
        return self.model(image, radar).float()


class WithRadar(Graph):
    def forward(self, image, radar):
        return self.run(image, radar)


class ImageOnly(Graph):
    def forward(self, image):
        return self.run(image, None)


def build(weights, config_path):
    cfg = dt.load_config(None, config_path)
    model = dt.DepthSense(cfg)
    tensors, _ = dt.read_safetensors(weights)
    missing, unexpected = model.net.load_state_dict(tensors, strict=False)
    missing = [k for k in missing if not k.endswith("num_batches_tracked")]
    if missing or unexpected:
        raise ValueError(f"{weights}: the weights do not fit the config: missing {missing[:5]}, "
                         f"unexpected {unexpected[:5]}")
    return cfg, model.eval()


def example_inputs(cfg, batch, with_radar):
    n = 2 if batch == "dynamic" else int(batch)
    h, w = cfg["out_height"], cfg["out_width"]
    g = torch.Generator().manual_seed(0)
    image = torch.rand(n, 3, h, w, generator=g)
    if not with_radar:
        return (image,)
    c = cfg["radar_channels"]
    radar = (torch.rand(n, c, h, w, generator=g) < 0.03) * 40.0
    return (image, radar)


def export(a):
    cfg, model = build(a.weights, a.config)
    with_radar = cfg["fusion"] != "none"
    half = a.precision == "fp16"
    graph = (WithRadar if with_radar else ImageOnly)(model, half).eval()
    inputs = example_inputs(cfg, a.batch, with_radar)
    names = ["image", "radar"][:len(inputs)]
    traced = None
    onnx_files = []
    for fmt, out in zip(a.format, a.out):
        if fmt == "pytorch":
            # The DepthNet's state dict under depthsense's names (`DepthSense(cfg).net`), with
            # the config beside it: `torch.load` gives {"config": …, "state_dict": …}.
            sd = {k: v.float() for k, v in model.net.state_dict().items()}
            torch.save({"format": "depthsense-pytorch-v1", "config": cfg, "state_dict": sd}, out)
            continue
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if traced is None:  # one trace serves every graph format
                traced = torch.jit.trace(graph, inputs, check_trace=False)
            if fmt == "torchscript":
                traced.save(out)
                continue
            dynamic = {n: {0: "N"} for n in names + ["depth"]} if a.batch == "dynamic" else None
            torch.onnx.export(traced, inputs, out, dynamo=False, opset_version=OPSET,
                              input_names=names, output_names=["depth"], dynamic_axes=dynamic,
                              do_constant_folding=True)
            onnx_files.append(out)
    if not onnx_files:
        return 0
    try:
        import onnx
    except ImportError as e:
        print(f"onnx is not importable by {sys.executable} (make setup installs it): {e}",
              file=sys.stderr)
        return 77
    for out in onnx_files:
        onnx.checker.check_model(onnx.load(out), full_check=True)
    return 0


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--weights", required=True, help="safetensors: the network's variables")
    p.add_argument("--config", required=True, help="the model config JSON")
    p.add_argument("--format", required=True, action="append",
                   choices=["onnx", "torchscript", "pytorch"],
                   help="repeatable, one --out each: several formats from one trace")
    p.add_argument("--out", required=True, action="append", help="the file to write")
    p.add_argument("--batch", default="dynamic", help="N or dynamic")
    p.add_argument("--precision", default="fp32", choices=["fp32", "fp16"])
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    a = p.parse_args()
    if a.threads > 0:
        torch.set_num_threads(a.threads)
    if len(a.format) != len(a.out):
        print(f"{len(a.format)} --format but {len(a.out)} --out", file=sys.stderr)
        return 2
    if a.batch != "dynamic" and not (a.batch.isdigit() and int(a.batch) > 0):
        print(f"--batch {a.batch}: a positive number or 'dynamic'", file=sys.stderr)
        return 2
    try:
        return export(a)
    except (ValueError, KeyError, json.JSONDecodeError) as e:
        print(str(e), file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
