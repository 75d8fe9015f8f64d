#!/usr/bin/env python3
"""PyTorch eager reference of the depthsense networks, timed like `depthsense bench model`.

Issue 9: the figures that count are the ratios ours (tch) / PyTorch on the same GPU in the same
run. This script builds, in plain PyTorch:

* the `released` architecture of SPEC §6.1 and the `paper` architecture of SPEC §6 (and `tiny`),
  layer for layer as crates/model/src/{config,net,layers}.rs build them: same modules, same
  order, same strides/paddings/dilations, same initialisation rules, so the parameter count and
  the multiply-adds equal `depthsense model-info` (checked by
  crates/checkpoint/tests/model/torch_reference_params.rs);
* two ordinal heads/losses (`--ordinal`):
  - `released`: the authors' released code path (SPEC §6.1, §7): all 2K logit channels
    bilinearly upsampled (align_corners=True) to the full input size, `a = y[:, ::2].clone()`,
    `b = y[:, 1::2].clone()`, `cat`, clamp to [1e-8, 1e8], pairwise softmax, `p[:, 1].clone()`,
    decode = count of P_k >= 0.5; their loss form: dense N×K×H×W label tensors built with
    `ones` + `linspace(...).repeat(N, 1, H, W).long()` masks, log of clamped P and 1 − P, sum
    over K, mean over valid pixels. What is *not* reproduced: their SID/uniform branch swap
    (SPEC §7) — labels here are the SPEC's l = floor(K·ln(d/α)/ln(β/α)) clamped to 0..K and
    y_k = [k < l]. The swap changes which labels are computed, not the cost of computing them.
  - `efficient`: exactly what our Rust network computes (crates/model/src/ordinal.rs):
    z_k = b_k − a_k at low resolution (or, for configs with `clamp_logits` such as the
    `released` preset, 2K upsampled to out_height×out_width, clamped, then paired — as
    `DepthNet::forward_t` does), and the sparse BCE-with-logits loss that interpolates z at the
    valid target pixels only (`ordinal_loss`: nonzero → four bilinear taps → softplus − y·z).
  - `efficient-dense`: as `efficient` but the dense loss (`ordinal_loss_dense`: z upsampled to
    H×W, BCE with logits everywhere, masked mean).
* what is timed per phase: `forward` = the network to its head output as `DepthNet::forward_t`
  returns it (efficient modes: z; `released` mode: their model forward, which ends with the
  upsampling, plus their ordinal layer, i.e. what their inference runs); `forward_decode` adds
  the decoding to metres at full resolution; `train_step` as below.
* timing as crates/cli/src/cmd/bench_model.rs: random inputs with the same densities (image
  N(0,1); radar 3 % of pixels at U(2, 62) m; target 8 % of pixels at U(1.5, 79.5) m), warm-up,
  CUDA synchronise before reading the clock, median of repeats; forward (head output), forward
  + decode to full-resolution depth, and a training step (zero_grad, forward in train mode,
  loss, backward, SGD momentum 0.9, weight decay 1e-4, lr 1e-3); fp32 or bf16 autocast,
  channels-last, cudnn.benchmark; bf16 precision check (fraction of pixels whose decoded level
  moves by > 1 bin versus fp32). The JSON has the same field names as `bench model --out`, plus
  `implementation`, `ordinal`, `torch` and the caching allocator's peaks per phase.

As in `bench model`, `--precision bf16` and `--channels-last` only apply on CUDA (fp32 NCHW on
the CPU, with a note).

Usage:
  python scripts/torch_reference.py --params-only --config released
  python scripts/torch_reference.py --config released --device cuda --precision bf16 \
      --channels-last --ordinal released --out ref.json
  python scripts/torch_reference.py --config released --device cuda \
      --variants fp32,bf16,bf16-cl --ordinal released,efficient --out ref.json   # one process
"""

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time

try:
    import torch
    import torch.nn as nn
    import torch.nn.functional as F
except ImportError as e:  # the Rust test skips on exit code 77
    print(f"torch not importable: {e}", file=sys.stderr)
    sys.exit(77)


# --------------------------------------------------------------------------------------------
# The networks, their configurations, SID decoding and losses: python/depthsense_torch.py (one
# module for this benchmark and for PyTorch users).

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # the GPU bundle: side by side
from depthsense_torch import *  # noqa: E402,F401,F403


class Runner:
    """forward / decode / loss of one network with one ordinal mode, as bench model calls them."""

    def __init__(self, net, mode):
        self.net, self.cfg, self.mode = net, net.cfg, mode
        if self.cfg["head"] != "ordinal":
            self.mode = "regression"

    def forward(self, image, radar):
        """The head output `bench model` times as `forward`: `DepthNet::forward_t`
        (`head_output`), or the released code's ordinal layer."""
        if self.mode == "released":
            h, w = image.shape[-2:]
            up = F.interpolate(self.net(image, radar), size=(h, w), mode="bilinear",
                               align_corners=True)
            # The released layer's `.clone().view(...)` assumes NCHW strides: with a channels-last
            # network the logits come back channels-last and the view fails (first H200 run).
            return released_ordinal_layer(up.contiguous())
        return head_output(self.net, image, radar)

    def decode(self, out, h, w):
        if self.mode == "released":
            return levels_to_depth(self.cfg["sid"], self.levels(out, h, w))
        return decode(self.cfg, out, h, w)

    def levels(self, out, h, w):
        if self.mode == "released":
            return out[0]
        return (upsample(out, h, w, self.cfg["align_corners"]) >= 0).sum(1, keepdim=True)

    def loss(self, out, target):
        cfg, sid, ac = self.cfg, self.cfg["sid"], self.cfg["align_corners"]
        if self.mode == "regression":
            return regression_loss(out, target, cfg["head"] == "l2", ac)
        if self.mode == "released":
            return released_loss(out[1], target, sid)
        if self.mode == "efficient-dense":
            return ordinal_loss_dense(out, target, sid, ac)
        return ordinal_loss_sparse(out, target, sid, ac)


# --------------------------------------------------------------------------------------------
# Counting (report.rs: trainable parameters; conv multiply-adds per image)

def count(cfg, height, width):
    with torch.device("meta"):
        net = DepthNet(cfg)
        params = sum(p.numel() for p in net.parameters() if p.requires_grad)
        macs = []

        def hook(m, inp, out):
            macs.append(m.in_channels * m.out_channels * m.kernel_size[0] * m.kernel_size[1]
                        * out.shape[-2] * out.shape[-1])

        for m in net.modules():
            if isinstance(m, nn.Conv2d):
                m.register_forward_hook(hook)
        net.eval()
        with torch.no_grad():
            net(torch.zeros(1, 3, height, width),
                torch.zeros(1, cfg["radar_channels"], height, width))
    return params, sum(macs)


# --------------------------------------------------------------------------------------------
# Timing (crates/cli/src/cmd/bench_model.rs)

def sync(dev):
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def time_it(dev, warmup, repeats, batch, f):
    for _ in range(warmup):
        f()
    sync(dev)
    ms = []
    for _ in range(max(repeats, 1)):
        t = time.perf_counter()
        f()
        sync(dev)
        ms.append((time.perf_counter() - t) * 1e3)
    med = statistics.median(ms)
    return {"batch": batch, "median_ms": med, "min_ms": min(ms), "mean_ms": sum(ms) / len(ms),
            "images_per_s": batch / (med / 1e3), "gpu_memory_mib": None}


def nvidia_smi(args):
    try:
        r = subprocess.run(["nvidia-smi"] + args, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return r.stdout.strip() if r.returncode == 0 else None


def gpu_used_total_mib(dev):
    if dev.type != "cuda":
        return None
    s = nvidia_smi(["--query-gpu=memory.used", "--format=csv,noheader,nounits",
                    f"--id={dev.index or 0}"])
    try:
        return int(s.splitlines()[0].strip())
    except (AttributeError, IndexError, ValueError):
        return None


def gpu_memory_mib(dev, baseline):
    """Same method as bench model: this PID's used_memory, else device used − baseline."""
    if dev.type != "cuda":
        return None
    s = nvidia_smi(["--query-compute-apps=pid,used_memory", "--format=csv,noheader,nounits"])
    me = str(os.getpid())
    for line in (s or "").splitlines():
        parts = [p.strip() for p in line.split(",")]
        if len(parts) >= 2 and parts[0] == me:
            try:
                return int(parts[1])
            except ValueError:
                pass
    tot = gpu_used_total_mib(dev)
    return None if tot is None else max(tot - (baseline or 0), 0)


def inputs(cfg, b, h, w, dev, cl):
    img = torch.randn(b, 3, h, w, device=dev)
    rc = cfg["radar_channels"]
    mask = torch.rand(b, rc, h, w, device=dev) < 0.03
    radar = (torch.rand(b, rc, h, w, device=dev) * 60.0 + 2.0) * mask
    valid = torch.rand(b, 1, h, w, device=dev) < 0.08
    target = (torch.rand(b, 1, h, w, device=dev) * 78.0 + 1.5) * valid
    if cl:
        img = img.contiguous(memory_format=torch.channels_last)
        radar = radar.contiguous(memory_format=torch.channels_last)
    return img, radar, target


def autocast(dev, prec):
    if prec == "fp32":
        return torch.autocast(device_type=dev.type, enabled=False)
    dtype = torch.bfloat16 if prec == "bf16" else torch.float16
    return torch.autocast(device_type="cuda", dtype=dtype)


def allocator_peaks(dev):
    if dev.type != "cuda":
        return None
    return {"torch_peak_allocated_mib": torch.cuda.max_memory_allocated(dev) / 2**20,
            "torch_peak_reserved_mib": torch.cuda.max_memory_reserved(dev) / 2**20}


def reset_peaks(dev):
    if dev.type == "cuda":
        torch.cuda.reset_peak_memory_stats(dev)


def bench(cfg, a, dev, prec, cl, mode, baseline):
    notes = []
    requested = prec + ("-cl" if cl else "")
    if cl and dev.type != "cuda":
        notes.append("--channels-last is only used on CUDA (as bench model); NCHW here")
        cl = False
    if prec != "fp32" and dev.type != "cuda":
        notes.append(f"--precision {prec} needs CUDA (as bench model); fp32 here")
        prec = "fp32"
    torch.manual_seed(0)
    net = DepthNet(cfg).to(dev)
    if cl:
        net = net.to(memory_format=torch.channels_last)
    run = Runner(net, mode)
    h, w = a.height, a.width
    params, macs = count(cfg, h, w)
    res = {
        "config": cfg["name"],
        "device": "cpu" if dev.type == "cpu" else f"cuda:{dev.index or 0}",
        "gpu": nvidia_smi(["--query-gpu=name", "--format=csv,noheader"])
        if dev.type == "cuda" else None,
        "precision": prec,
        "channels_last": cl,
        "cudnn_benchmark": bool(a.cudnn_benchmark and dev.type == "cuda"),
        "height": h,
        "width": w,
        "params": params,
        "macs_per_image": macs,
        "threads": torch.get_num_threads(),
        "warmup": a.warmup,
        "repeats": a.repeats,
        "forward": None,
        "forward_decode": None,
        "train_step": None,
        "precision_check": None,
        "implementation": "pytorch-eager",
        "variant_requested": requested,
        "ordinal": run.mode,
        "torch": torch.__version__,
        "notes": notes,
    }
    if a.batch_forward > 0:
        img, radar, _ = inputs(cfg, a.batch_forward, h, w, dev, cl)
        net.eval()
        with torch.no_grad():
            reset_peaks(dev)

            def fwd():
                with autocast(dev, prec):
                    run.forward(img, radar)

            t = time_it(dev, a.warmup, a.repeats, a.batch_forward, fwd)
            t["gpu_memory_mib"] = gpu_memory_mib(dev, baseline)
            t["allocator"] = allocator_peaks(dev)
            res["forward"] = t
            reset_peaks(dev)

            def fwd_dec():
                with autocast(dev, prec):
                    run.decode(run.forward(img, radar), h, w)

            t = time_it(dev, a.warmup, a.repeats, a.batch_forward, fwd_dec)
            t["gpu_memory_mib"] = gpu_memory_mib(dev, baseline)
            t["allocator"] = allocator_peaks(dev)
            res["forward_decode"] = t
            if prec != "fp32" and run.mode != "regression":
                l32 = run.levels(run.forward(img, radar), h, w)
                with autocast(dev, prec):
                    o = run.forward(img, radar)
                o = tuple(x.float() for x in o) if isinstance(o, tuple) else o.float()
                lmp = run.levels(o, h, w)
                d = (l32.long() - lmp.long()).abs()
                n = d.numel()
                gt1 = (d > 1).sum().item() / n
                res["precision_check"] = {
                    "frac_pixels_level_moved_gt_1": gt1,
                    "frac_pixels_level_moved": (d > 0).sum().item() / n,
                    "target_frac_gt_1": 0.001,
                    "ok": gt1 <= 0.001,
                    "note": "random weights and inputs; re-check on a trained checkpoint",
                }
        del img, radar
    if a.batch_train > 0:
        img, radar, target = inputs(cfg, a.batch_train, h, w, dev, cl)
        net.train()
        # SPEC §8 optimiser, as bench model: SGD, momentum 0.9, weight decay 1e-4, lr 1e-3.
        opt = torch.optim.SGD(net.parameters(), lr=1e-3, momentum=0.9, weight_decay=1e-4)
        reset_peaks(dev)

        def step():
            opt.zero_grad()
            with autocast(dev, prec):
                loss = run.loss(run.forward(img, radar), target)
            loss.backward()
            opt.step()

        t = time_it(dev, a.warmup, a.repeats, a.batch_train, step)
        t["gpu_memory_mib"] = gpu_memory_mib(dev, baseline)
        t["allocator"] = allocator_peaks(dev)
        res["train_step"] = t
        del opt, img, radar, target
    del net, run
    if dev.type == "cuda":
        torch.cuda.empty_cache()
    return res


def profile_train(cfg, a, dev, top=25):
    """Issue 44: where the training step's time goes in NCHW and in channels-last — PyTorch's
    profiler over a few steps of the same network (fp32, the released ordinal form), the
    operators with the most self time on the device (CUDA) or the CPU, per layout."""
    from torch.profiler import ProfilerActivity, profile
    out = {"config": cfg["name"], "device": str(dev), "batch": a.batch_train,
           "height": a.height, "width": a.width, "torch": torch.__version__, "layouts": {}}
    cuda = dev.type == "cuda"
    for cl in (False, True):
        if cl and not cuda:
            out["layouts"]["channels_last"] = {"note": "channels-last is only used on CUDA"}
            continue
        torch.manual_seed(0)
        net = DepthNet(cfg).to(dev)
        if cl:
            net = net.to(memory_format=torch.channels_last)
        run = Runner(net, "released")
        img, radar, target = inputs(cfg, a.batch_train, a.height, a.width, dev, cl)
        net.train()
        opt = torch.optim.SGD(net.parameters(), lr=1e-3, momentum=0.9, weight_decay=1e-4)

        def step():
            opt.zero_grad()
            run.loss(run.forward(img, radar), target).backward()
            opt.step()

        for _ in range(max(a.warmup, 1)):
            step()
        sync(dev)
        acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
        with profile(activities=acts) as prof:
            for _ in range(max(a.repeats, 1)):
                step()
            sync(dev)
        key = "self_device_time_total" if cuda else "self_cpu_time_total"
        rows = []
        for e in prof.key_averages():
            t = getattr(e, key, None)
            if t is None and cuda:
                t = getattr(e, "self_cuda_time_total", 0)
            rows.append({"op": e.key, "calls": e.count,
                         "self_ms_per_step": (t or 0) / 1e3 / max(a.repeats, 1)})
        rows.sort(key=lambda r: -r["self_ms_per_step"])
        total = sum(r["self_ms_per_step"] for r in rows)
        out["layouts"]["channels_last" if cl else "nchw"] = {
            "self_ms_per_step_total": total, "top": rows[:top]}
        del net, run, opt, img, radar, target
        if cuda:
            torch.cuda.empty_cache()
    return out


def fmt_row(r):
    def ms(t):
        return "-" if t is None else f"{t['median_ms']:.2f}"

    def mem(t):
        if t is None:
            return "-"
        al = t.get("allocator")
        return f"{al['torch_peak_reserved_mib']:.0f}" if al else "-"

    return (f"{r['config']:<9} {r['ordinal']:<16} {r['precision']:<5} "
            f"{'cl' if r['channels_last'] else '  '} {ms(r['forward']):>10} "
            f"{ms(r['forward_decode']):>10} {ms(r['train_step']):>11} {mem(r['train_step']):>9}")


def check(d):
    """`--check DIR`: DIR/config.json (a ModelConfig), DIR/weights.safetensors (a depthsense
    VarStore), DIR/shape.json {batch, height, width}, DIR/image.f32, DIR/radar.f32 (little-endian
    f32). Loads the weights under our names (every key and shape must match), runs the head
    output in eval mode in fp32 on the CPU (`DepthNet::forward_t`) and writes DIR/z.f32."""
    cfg = load_config(None, os.path.join(d, "config.json"))
    with open(os.path.join(d, "shape.json")) as f:
        sh = json.load(f)
    b, h, w = sh["batch"], sh["height"], sh["width"]
    net = DepthNet(cfg)
    ours, _ = read_safetensors(os.path.join(d, "weights.safetensors"))
    mine = {k: v for k, v in net.state_dict().items() if not k.endswith("num_batches_tracked")}
    missing = sorted(set(mine) - set(ours))
    unexpected = sorted(set(ours) - set(mine))
    shapes = sorted(f"{k}: ours {list(ours[k].shape)} PyTorch {list(mine[k].shape)}"
                    for k in set(mine) & set(ours) if ours[k].shape != mine[k].shape)
    rep = {"keys": len(mine), "missing_in_depthsense": missing,
           "unexpected_from_depthsense": unexpected, "shape_mismatch": shapes}
    if missing or unexpected or shapes:
        print(json.dumps(rep))
        return 1
    net.load_state_dict(ours, strict=False)
    net.eval()

    def raw(name, c):
        with open(os.path.join(d, name), "rb") as f:
            return torch.frombuffer(bytearray(f.read()), dtype=torch.float32).reshape(b, c, h, w)

    image, radar = raw("image.f32", 3), raw("radar.f32", cfg["radar_channels"])
    with torch.no_grad():
        z = Runner(net, "efficient").forward(image, radar).float().contiguous()
    with open(os.path.join(d, "z.f32"), "wb") as f:
        try:
            f.write(z.numpy().tobytes())
        except (ImportError, RuntimeError):  # torch without numpy
            f.write(bytes(z.view(-1).view(torch.uint8).tolist()))
    rep["z_shape"] = list(z.shape)
    # The deployment contract: RGB in [0, 1] (normalised inside), depth in metres at the
    # configured output size, decoded as `DepthNet::decode`.
    deploy = DepthSense(cfg)
    deploy.net = net
    deploy.eval()
    image01 = image * deploy.std + deploy.mean
    with torch.no_grad():
        depth = deploy(image01, radar if cfg["fusion"] != "none" else None).float().contiguous()
    with open(os.path.join(d, "depth.f32"), "wb") as f:
        f.write(bytes(depth.view(-1).view(torch.uint8).tolist()))
    rep["depth_shape"] = list(depth.shape)
    print(json.dumps(rep))
    return 0


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", "--preset", dest="preset", default="released",
                   help="released, paper or tiny; comma-separated for several (one process); "
                   "--config as `bench model` names it (--preset: the old name)")
    p.add_argument("--config-json", help="a ModelConfig JSON (`model-info --print-config`) "
                   "or a `model-info --json` report instead of --config")
    p.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    p.add_argument("--precision", default="fp32", choices=["fp32", "bf16", "fp16"])
    p.add_argument("--channels-last", action="store_true")
    p.add_argument("--variants", help="comma-separated precision[-cl] list (fp32, bf16, "
                   "bf16-cl, ...) instead of --precision/--channels-last")
    p.add_argument("--ordinal", default="released",
                   help="released, efficient or efficient-dense; comma-separated for several")
    p.add_argument("--batch-forward", type=int, default=3)
    p.add_argument("--batch-train", type=int, default=8)
    p.add_argument("--height", type=int, default=350)
    p.add_argument("--width", type=int, default=800)
    p.add_argument("--warmup-runs", "--warmup", dest="warmup", type=int, default=3,
                   help="untimed runs before the timed ones (as `bench model --warmup-runs`)")
    p.add_argument("--repeats", type=int, default=10)
    p.add_argument("--cudnn-benchmark", default="true", choices=["true", "false"])
    p.add_argument("--threads", type=int, help="CPU threads (default: torch's choice)")
    p.add_argument("--params-only", action="store_true",
                   help="print {params, macs_per_image} (meta device, no allocation) and exit")
    p.add_argument("--out", help="write the JSON here (one object, or {\"runs\": [...]})")
    p.add_argument("--profile-train", action="store_true",
                   help="instead of timing: PyTorch's profiler over --repeats training steps of "
                   "the first --config in NCHW and channels-last (CUDA), the operators with "
                   "the most self time per layout, to --out")
    p.add_argument("--check", metavar="DIR", help="load a depthsense VarStore and write its head "
                   "output for given inputs (see check(); used by the Rust test)")
    a = p.parse_args()
    a.cudnn_benchmark = a.cudnn_benchmark == "true"
    if a.threads:
        torch.set_num_threads(a.threads)
    if a.check:
        return check(a.check)
    presets = [s.strip() for s in a.preset.split(",") if s.strip()]
    cfgs = [load_config(None, a.config_json)] if a.config_json else \
        [load_config(s, None) for s in presets]
    if a.params_only:
        outs = []
        for c in cfgs:
            params, macs = count(c, a.height, a.width)
            outs.append({"config": c["name"], "params": params, "macs_per_image": macs,
                         "height": a.height, "width": a.width})
        text = json.dumps(outs[0] if len(outs) == 1 else {"runs": outs})
        print(text)
        if a.out:
            with open(a.out, "w") as f:
                f.write(text + "\n")
        return 0
    dev = torch.device(a.device)
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            print("error: --device cuda but torch.cuda.is_available() is False", file=sys.stderr)
            return 2
        torch.backends.cudnn.benchmark = a.cudnn_benchmark
    if a.profile_train:
        prof = profile_train(cfgs[0], a, dev)
        for k, v in prof["layouts"].items():
            for r in v.get("top", [])[:8]:
                print(f"{k:<14} {r['self_ms_per_step']:9.2f} ms/step  {r['calls']:6d}x  {r['op']}")
        if a.out:
            with open(a.out, "w") as f:
                json.dump(prof, f, indent=2)
        return 0
    if a.variants:
        variants = []
        for v in a.variants.split(","):
            v = v.strip()
            variants.append((v[:-3], True) if v.endswith("-cl") else (v, False))
    else:
        variants = [(a.precision, a.channels_last)]
    modes = [m.strip() for m in a.ordinal.split(",") if m.strip()]
    for m in modes:
        if m not in ("released", "efficient", "efficient-dense"):
            p.error(f"--ordinal {m}: expected released, efficient or efficient-dense")
    baseline = gpu_used_total_mib(dev)
    runs = []
    failed = False
    print(f"{'config':<9} {'ordinal':<16} {'prec':<5} cl {'fwd ms':>10} {'fwd+dec ms':>10} "
          f"{'train ms':>11} {'peak MiB':>9}", flush=True)
    for cfg in cfgs:
        for prec, cl in variants:
            for mode in modes:
                try:
                    r = bench(cfg, a, dev, prec, cl, mode, baseline)
                except Exception as e:  # noqa: BLE001 — e.g. the released form OOM at batch 8:
                    # recorded, and the other variants still run
                    oom = isinstance(e, torch.cuda.OutOfMemoryError)
                    msg = "CUDA out of memory" if oom else f"{type(e).__name__}"
                    r = {"config": cfg["name"], "ordinal": mode, "precision": prec,
                         "channels_last": cl, "implementation": "pytorch-eager",
                         "variant_requested": prec + ("-cl" if cl else ""),
                         "error": f"{msg}: {str(e)[:300]}"}
                    if dev.type == "cuda":
                        torch.cuda.empty_cache()
                    print(f"{cfg['name']:<9} {mode:<16} {prec:<5} {'cl' if cl else '  '} "
                          f"failed: {msg}: {str(e)[:200]}", flush=True)
                    runs.append(r)
                    failed = True
                    continue
                runs.append(r)
                print(fmt_row(r), flush=True)
                for n in r["notes"]:
                    print(f"note: {n}", file=sys.stderr)
                if r["precision_check"]:
                    print(f"  precision check vs fp32: {json.dumps(r['precision_check'])}")
                if a.out:  # rewritten after every run: a timeout keeps what finished
                    with open(a.out, "w") as f:
                        json.dump(runs[0] if len(runs) == 1 and len(cfgs) * len(variants)
                                  * len(modes) == 1 else {"runs": runs}, f, indent=2)
    if a.out:  # the failed runs too
        with open(a.out, "w") as f:
            json.dump(runs[0] if len(runs) == 1 and len(cfgs) * len(variants)
                      * len(modes) == 1 else {"runs": runs}, f, indent=2)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
