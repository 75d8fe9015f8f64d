#!/usr/bin/env python3
"""PyTorch eager reference of the depthsense networks, timed like `depthsense bench model`.

Issue 9: the figures that count are the ratios ours (tch) / PyTorch on the same GPU in the same
run. This script builds, in plain PyTorch:

* the `released` architecture of SPEC §6.1 and the `paper` architecture of SPEC §6 (and `tiny`),
  layer for layer as crates/model/src/{config,net,layers}.rs build them: same modules, same
  order, same strides/paddings/dilations, same initialisation rules, so the parameter count and
  the multiply-adds equal `depthsense model-info` (checked by
  crates/model/tests/torch_reference_params.rs);
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
  python scripts/torch_reference.py --params-only --preset released
  python scripts/torch_reference.py --preset released --device cuda --precision bf16 \
      --channels-last --ordinal released --out ref.json
  python scripts/torch_reference.py --preset released --device cuda \
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
# Configurations (crates/model/src/config.rs; serde field names, so a `model-info
# --print-config` / `--json` config can be passed with --config-json)

def paper():
    return {
        "name": "paper",
        "backbone_depth": 101,
        "backbone_width": 64,
        "stem": "torchvision",
        "decoder": "topdown",
        "decoder_channels": 256,
        "fusion": "late",
        "attention": True,
        "attention_gate": "bounded",
        "head": "ordinal",
        "head_channels": 512,
        "head_pre_dropout": False,
        "dropout": 0.5,
        "radar_channels": 1,
        "radar_in_metres": False,
        "clamp_logits": False,
        "radar_branch": "basic",
        "radar_width": 64,
        "radar_out_channels": 512,
        "sid": {"bins": 80, "alpha_m": 1.0, "beta_m": 80.0, "decode_offset_m": 0.0},
        "align_corners": True,
        "input_downscale": 1,
        "out_height": 350,
        "out_width": 800,
    }


def released():
    c = paper()
    c.update({
        "name": "released",
        "stem": "deep",
        "decoder": "released",
        "attention": False,
        "head_channels": 2048,
        "head_pre_dropout": True,
        "radar_in_metres": True,
        "clamp_logits": True,
        "radar_branch": "bottleneck",
    })
    c["sid"] = dict(c["sid"], decode_offset_m=0.3)
    return c


def dropout_for_head(head_channels):
    return 0.5 * min(max(head_channels / 512.0, 0.0), 1.0)


def tiny():
    c = paper()
    c.update({
        "name": "tiny",
        "backbone_depth": 18,
        "backbone_width": 16,
        "decoder_channels": 32,
        "head_channels": 32,
        "radar_width": 8,
        "radar_out_channels": 64,
        "dropout": dropout_for_head(32),
    })
    return c


PRESETS = {"paper": paper, "released": released, "tiny": tiny}


# `ModelConfig` fields with `#[serde(default …)]` (crates/model/src/config.rs): their value when
# a config JSON does not hold them (checkpoints written before the field existed, or the field at
# its default and skipped when serialising).
SERDE_DEFAULTS = {
    "radar_input": "height",
    "radar_in_metres": False,
    "clamp_logits": False,
    "attention_gate": "double",
    "input_downscale": 1,
    "radar_downscale": None,
    "radar_skip_channels": 0,
}


def load_config(preset, config_json):
    if config_json:
        with open(config_json) as f:
            c = json.load(f)
        if "config" in c and isinstance(c["config"], dict):  # `model-info --json` report
            c = c["config"]
        # A field a ModelConfig JSON leaves out takes serde's default (what the Rust side reads),
        # not the paper preset's value.
        for k, v in SERDE_DEFAULTS.items():
            c.setdefault(k, v)
        base = paper()
        base.update(c)
        return base
    return PRESETS[preset]()


# --------------------------------------------------------------------------------------------
# Layers (crates/model/src/layers.rs). Module attribute names follow our var-store names, so
# `state_dict()` keys equal `DepthNet`'s variables (`rgb.layer1.0.conv1.weight`, …; PyTorch's
# extra `num_batches_tracked` buffers aside) and a depthsense checkpoint loads directly
# (`--check`, crates/model/tests/torch_reference_params.rs).

def conv(cin, cout, k, stride=1, pad=0, dil=1, bias=True, init="pytorch"):
    """nn.Conv2d with the Rust initialisation rules (`ConvInit`)."""
    m = nn.Conv2d(cin, cout, k, stride, pad, dil, bias=bias)
    if init == "pytorch":
        pass  # nn.Conv2d's own reset: weight and bias ~ U(±1/sqrt(fan_in))
    elif init == "resnet":  # torchvision ResNet: kaiming_normal fan_out, bias 0
        nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
        if bias:
            nn.init.zeros_(m.bias)
    elif init == "zero":
        nn.init.zeros_(m.weight)
        if bias:
            nn.init.zeros_(m.bias)
    return m


def conv_bn(cin, cout, k, stride, pad, dil):
    """`ConvBn`: conv (no bias, torchvision init) and BatchNorm (γ = 1, β = 0, eps 1e-5,
    momentum 0.1, as tch)."""
    return conv(cin, cout, k, stride, pad, dil, bias=False, init="resnet"), nn.BatchNorm2d(cout)


class Block(nn.Module):
    """Basic block or v1.5 bottleneck (stride and dilation on the 3x3), as `layers::Block`."""

    def __init__(self, kind, cin, planes, stride, dil):
        super().__init__()
        exp = 4 if kind == "bottleneck" else 1
        out = planes * exp
        if kind == "basic":
            self.conv1, self.bn1 = conv_bn(cin, planes, 3, stride, dil, dil)
            self.conv2, self.bn2 = conv_bn(planes, planes, 3, 1, dil, dil)
            self.conv3 = self.bn3 = None
        else:
            self.conv1, self.bn1 = conv_bn(cin, planes, 1, 1, 0, 1)
            self.conv2, self.bn2 = conv_bn(planes, planes, 3, stride, dil, dil)
            self.conv3, self.bn3 = conv_bn(planes, out, 1, 1, 0, 1)
        self.downsample = (nn.Sequential(*conv_bn(cin, out, 1, stride, 0, 1))
                           if (stride != 1 or cin != out) else None)

    def forward(self, x):
        y = F.relu(self.bn1(self.conv1(x)))
        y = self.bn2(self.conv2(y))
        if self.conv3 is not None:
            y = self.bn3(self.conv3(F.relu(y)))
        s = x if self.downsample is None else self.downsample(x)
        return F.relu(y + s)


def standard_spec(depth, in_channels, width, stem):
    block, blocks = {
        18: ("basic", [2, 2, 2, 2]),
        34: ("basic", [3, 4, 6, 3]),
        50: ("bottleneck", [3, 4, 6, 3]),
    }.get(depth, ("bottleneck", [3, 4, 23, 3]))
    return dict(in_channels=in_channels, width=width, stem=stem, block=block, blocks=blocks,
                strides=[1, 2, 2, 2], dilations=[1, 1, 1, 1])


class ResNet(nn.Module):
    """`layers::ResNet`: stem conv1/bn1.. (torchvision / deep / radar), max-pool,
    layer1..layer4 → C1..C4."""

    def __init__(self, s):
        super().__init__()
        w = s["width"]
        stem = s["stem"]
        if stem == "torchvision":
            convs = [(s["in_channels"], w, 7, 2, 3)]
            cin = w
        elif stem == "deep":  # SPEC §6.1 image stem
            convs = [(s["in_channels"], w, 3, 2, 1), (w, w, 3, 1, 1), (w, 2 * w, 3, 1, 1)]
            cin = 2 * w
        elif stem == "radar":  # SPEC §6.1 radar stem
            convs = [(s["in_channels"], w, 3, 2, 1), (w, w, 3, 1, 1), (w, w, 3, 1, 1),
                     (w, 2 * w, 7, 2, 3)]
            cin = 2 * w
        else:
            raise ValueError(f"stem {stem}")
        self.n_stem = len(convs)
        for i, (a, b, k, st, p) in enumerate(convs, 1):
            c, bn = conv_bn(a, b, k, st, p, 1)
            setattr(self, f"conv{i}", c)
            setattr(self, f"bn{i}", bn)
        self.pool = (7, 4, 1) if stem == "radar" else (3, 2, 1)
        exp = 4 if s["block"] == "bottleneck" else 1
        self.channels = []
        for li in range(4):
            planes = w << li
            blocks = nn.ModuleList()
            for bi in range(s["blocks"][li]):
                stride = s["strides"][li] if bi == 0 else 1
                blocks.append(Block(s["block"], cin, planes, stride, s["dilations"][li]))
                cin = planes * exp
            self.channels.append(cin)
            setattr(self, f"layer{li + 1}", blocks)

    def forward(self, x):
        for i in range(1, self.n_stem + 1):
            x = F.relu(getattr(self, f"bn{i}")(getattr(self, f"conv{i}")(x)))
        k, s, p = self.pool
        x = F.max_pool2d(x, k, s, p)
        outs = []
        for li in range(1, 5):
            for b in getattr(self, f"layer{li}"):
                x = b(x)
            outs.append(x)
        return outs


def resize_to(x, hw, nearest):
    if tuple(x.shape[-2:]) == tuple(hw):
        return x
    if nearest:
        return F.interpolate(x, size=hw, mode="nearest")
    return F.interpolate(x, size=hw, mode="bilinear", align_corners=False)


class Fpn(nn.Module):
    """The released decoder's `fpn`: P3_1..P5_1 laterals, P3_2..P5_2 smoothing."""

    def __init__(self, cin, ch):
        super().__init__()
        for i in range(3):
            setattr(self, f"P{i + 3}_1", conv(cin[i], ch, 1))
            setattr(self, f"P{i + 3}_2", conv(ch, ch, 3, 1, 1))


class Decoder(nn.Module):
    """`net::Decoder`: top-down (paper: lateral2..4, smooth2..4) or released (`fpn` reduced to
    stride 32 by convfeat1..3)."""

    def __init__(self, kind, cin, ch):
        super().__init__()
        self.kind = kind
        if kind == "topdown":
            for i in range(3):
                setattr(self, f"lateral{i + 2}", conv(cin[i], ch, 1))
            for i in range(3):
                setattr(self, f"smooth{i + 2}", conv(ch, ch, 3, 1, 1))
            self.lateral = [getattr(self, f"lateral{i + 2}") for i in range(3)]
            self.smooth = [getattr(self, f"smooth{i + 2}") for i in range(3)]
        else:
            self.fpn = Fpn(cin, ch)
            self.lateral = [getattr(self.fpn, f"P{i + 3}_1") for i in range(3)]
            self.smooth = [getattr(self.fpn, f"P{i + 3}_2") for i in range(3)]
            self.convfeat1 = conv(ch, ch, 7, 4, 2, bias=False)
            self.convfeat2 = conv(ch, ch, 3, 2, 1, bias=False)
            self.convfeat3 = conv(ch, ch, 3, 1, 1, bias=False)
        self.out_channels = 3 * ch

    def forward(self, c):
        t4 = self.lateral[2](c[3])
        t3 = self.lateral[1](c[2]) + resize_to(t4, c[2].shape[-2:], True)
        t2 = self.lateral[0](c[1]) + resize_to(t3, c[1].shape[-2:], True)
        p2, p3, p4 = self.smooth[0](t2), self.smooth[1](t3), self.smooth[2](t4)
        if self.kind == "topdown":
            hw = p2.shape[-2:]
            return torch.cat([p2, resize_to(p3, hw, False), resize_to(p4, hw, False)], 1)
        f3 = F.relu(self.convfeat3(p4))
        hw = f3.shape[-2:]
        f1 = resize_to(F.relu(self.convfeat1(p2)), hw, False)
        f2 = resize_to(F.relu(self.convfeat2(p3)), hw, False)
        return torch.cat([f1, f2, f3], 1)


class RadarBranch(ResNet):
    """`net::RadarBranch`: a ResNet on the radar channels (basic: ResNet-18, torchvision stem;
    bottleneck: the released radar stem, strides 1/2/1/1, dilations 1/1/2/4, `conv_radar`)."""

    def __init__(self, cfg):
        if cfg["radar_branch"] == "basic":
            super().__init__(standard_spec(18, cfg["radar_channels"], cfg["radar_width"],
                                           "torchvision"))
            self.conv_radar = None
            self.out_channels = self.channels[3]
        else:
            super().__init__(dict(in_channels=cfg["radar_channels"], width=cfg["radar_width"],
                                  stem="radar", block="bottleneck", blocks=[2, 2, 2, 2],
                                  strides=[1, 2, 1, 1], dilations=[1, 1, 2, 4]))
            c, o = self.channels[3], cfg["radar_out_channels"]
            self.conv_radar = nn.Sequential(conv(c, o, 1), nn.ReLU(), conv(o, o, 1), nn.ReLU())
            self.out_channels = o

    def forward(self, x):
        y = super().forward(x)[-1]
        return y if self.conv_radar is None else self.conv_radar(y)


class Head(nn.Module):
    def __init__(self, fused, hidden, out):
        super().__init__()
        self.conv1 = conv(fused, hidden, 1)
        self.conv2 = conv(hidden, out, 1)


class Attention(nn.Module):
    def __init__(self):
        super().__init__()
        self.conv = conv(2, 1, 7, 1, 3, init="zero")


def pool_nearest(d, k, ceil_mode):
    """`net::pool_nearest`: the nearest non-zero depth of each k cell (max-pool of 1/d)."""
    inv = d.clamp_min(1e-6).reciprocal() * (d > 0).to(d.dtype)
    inv = F.max_pool2d(inv, k, k, 0, ceil_mode=ceil_mode)
    return inv.clamp_min(1e-12).reciprocal() * (inv > 0).to(inv.dtype)


class RadarSkip(nn.Module):
    """`net::RadarSkip`: the radar map at the head's resolution (nearest return per cell, ceil
    mode) → 3x3 conv + ReLU → 3x3 conv + ReLU."""

    def __init__(self, cin, ch):
        super().__init__()
        self.conv1 = conv(cin, ch, 3, 1, 1)
        self.conv2 = conv(ch, ch, 3, 1, 1)

    def forward(self, radar, hw):
        h, w = radar.shape[-2:]
        k = (-(-h // hw[0]), -(-w // hw[1]))
        r = resize_to(pool_nearest(radar, k, True), hw, True)
        return F.relu(self.conv2(F.relu(self.conv1(r))))


class DepthNet(nn.Module):
    """`net::DepthNet`: forward → [B,2K,h,w] ordinal logits or [B,1,h,w] metres
    (`forward_logits_t`)."""

    def __init__(self, cfg):
        super().__init__()
        self.cfg = cfg
        in_ch = 3 + (cfg["radar_channels"] if cfg["fusion"] == "early" else 0)
        self.rgb = ResNet(standard_spec(cfg["backbone_depth"], in_ch, cfg["backbone_width"],
                                        cfg["stem"]))
        ch = self.rgb.channels
        self.decoder = Decoder(cfg["decoder"], ch[1:], cfg["decoder_channels"])
        self.radar = RadarBranch(cfg) if cfg["fusion"] == "late" else None
        fused = self.decoder.out_channels + (self.radar.out_channels if self.radar else 0)
        skip = cfg.get("radar_skip_channels", 0) if cfg["fusion"] == "late" else 0
        self.radar_skip = RadarSkip(cfg["radar_channels"], skip) if skip > 0 else None
        fused += skip
        self.attention = Attention() if cfg["attention"] else None
        out = 2 * cfg["sid"]["bins"] if cfg["head"] == "ordinal" else 1
        self.head = Head(fused, cfg["head_channels"], out)

    def downscale_inputs(self, image, radar):
        s = self.cfg["input_downscale"]
        r = self.cfg.get("radar_downscale") or s
        if s > 1:
            image = F.avg_pool2d(image, s, s, 0, False, True)
        if r > 1:
            radar = pool_nearest(radar, r, False)
        return image, radar

    def forward(self, image, radar):
        cfg = self.cfg
        image, radar = self.downscale_inputs(image, radar)
        scale = 1.0 if cfg["radar_in_metres"] else 1.0 / cfg["sid"]["beta_m"]
        if cfg["fusion"] == "early":
            x = torch.cat([image, radar.to(image.dtype) * scale], 1)
        else:
            x = image
        f = self.decoder(self.rgb(x))
        if self.radar is not None:
            r = self.radar(radar.to(image.dtype) * scale)
            f = torch.cat([f, resize_to(r, f.shape[-2:], False)], 1)
        if self.radar_skip is not None:
            f = torch.cat([f, self.radar_skip(radar.to(image.dtype) * scale, f.shape[-2:])], 1)
        if self.attention is not None:
            mean = f.mean(1, keepdim=True)
            mx = f.amax(1, keepdim=True)
            gate = torch.sigmoid(self.attention.conv(torch.cat([mean, mx], 1)))
            # `AttentionGate`: a config without the field is the 2σ(s) gate
            if cfg.get("attention_gate", "double") == "bounded":
                f = f * (gate + 0.5)
            else:
                f = f * (gate * 2.0)
        p = cfg["dropout"]
        if cfg["head_pre_dropout"]:
            f = F.dropout2d(f, p, self.training)
        y = F.dropout2d(F.relu(self.head.conv1(f)), p, self.training)
        y = self.head.conv2(y)
        if cfg["head"] == "ordinal":
            return y
        return torch.sigmoid(y) * cfg["sid"]["beta_m"]


# --------------------------------------------------------------------------------------------
# Ordinal heads and losses (crates/model/src/ordinal.rs, sid.rs; the released code's form)

def upsample(x, h, w, ac):
    if tuple(x.shape[-2:]) == (h, w):
        return x
    return F.interpolate(x, size=(h, w), mode="bilinear", align_corners=ac)


def pair_differences(y):
    b, c, h, w = y.shape
    p = y.view(b, c // 2, 2, h, w)
    return p[:, :, 1] - p[:, :, 0]


def sid_labels(sid, depth):
    k = sid["bins"]
    scale = k / math.log(sid["beta_m"] / sid["alpha_m"])
    d = depth.float().clamp_min(sid["alpha_m"])
    return (torch.log(d / sid["alpha_m"]) * scale).floor().clamp(0, k).long()


def levels_to_depth(sid, level):
    step = math.log(sid["beta_m"] / sid["alpha_m"]) / sid["bins"]
    la = math.log(sid["alpha_m"])
    l = level.float()
    return (torch.exp(l * step + la) + torch.exp((l + 1) * step + la)) / 2 - sid["decode_offset_m"]


def taps(i, out, inp, ac):
    f = i.double()
    if ac:
        src = f * ((inp - 1) / (out - 1)) if out > 1 else f * 0.0
    else:
        src = ((f + 0.5) * (inp / out) - 0.5).clamp_min(0.0)
    i0 = src.floor().clamp(0, inp - 1)
    lam = (src - i0).clamp(0, 1)
    i0 = i0.long()
    return i0, (i0 + 1).clamp_max(inp - 1), lam


def ordinal_loss_sparse(z, target, sid, ac):
    """`ordinal::ordinal_loss`: z interpolated at the valid target pixels only."""
    b, k, h, w = z.shape
    th, tw = target.shape[-2:]
    z = z if z.dtype == torch.float64 else z.float()
    flat = target.reshape(-1)
    idx = (flat > 0).nonzero().squeeze(1)
    n = idx.shape[0]
    if n == 0:
        return z.sum() * 0.0
    depth = flat.index_select(0, idx)
    bi = torch.div(idx, th * tw, rounding_mode="floor")
    rem = idx.remainder(th * tw)
    yi = torch.div(rem, tw, rounding_mode="floor")
    xi = rem.remainder(tw)
    y0, y1, wy = taps(yi, th, h, ac)
    x0, x1, wx = taps(xi, tw, w, ac)
    rows = z.permute(0, 2, 3, 1).reshape(b * h * w, k)
    base = bi * (h * w)

    def tap(yy, xx):
        return rows.index_select(0, base + yy * w + xx)

    wy, wx = wy.to(z.dtype).unsqueeze(1), wx.to(z.dtype).unsqueeze(1)
    vy, vx = 1.0 - wy, 1.0 - wx
    top = tap(y0, x0) * vx + tap(y0, x1) * wx
    bottom = tap(y1, x0) * vx + tap(y1, x1) * wx
    zp = top * vy + bottom * wy
    label = sid_labels(sid, depth).unsqueeze(1)
    y = (torch.arange(k, device=z.device).unsqueeze(0) < label).to(z.dtype)
    return (F.softplus(zp) - y * zp).sum() / n


def ordinal_loss_dense(z, target, sid, ac):
    """`ordinal::ordinal_loss_dense`."""
    th, tw = target.shape[-2:]
    z = upsample(z, th, tw, ac)
    z = z if z.dtype == torch.float64 else z.float()
    k = z.shape[1]
    valid = (target > 0).to(z.dtype)
    label = sid_labels(sid, target)
    y = (torch.arange(k, device=z.device).view(1, k, 1, 1) < label).to(z.dtype)
    per_pixel = (F.softplus(z) - y * z).sum(1, keepdim=True)
    return (per_pixel * valid).sum() / valid.sum().clamp_min(1.0)


def regression_loss(pred, target, squared, ac):
    th, tw = target.shape[-2:]
    pred = upsample(pred, th, tw, ac).float()
    valid = (target > 0).float()
    d = (pred - target.float()) * valid
    e = d.square() if squared else d.abs()
    return e.sum() / valid.sum().clamp_min(1.0)


def released_ordinal_layer(y):
    """The released code's ordinal layer on upsampled logits [N,2K,H,W] → (levels, P)."""
    n, c, h, w = y.size()
    k = c // 2
    a = y[:, ::2, :, :].clone().view(n, 1, k * h * w)
    b = y[:, 1::2, :, :].clone().view(n, 1, k * h * w)
    pair = torch.clamp(torch.cat((a, b), dim=1), min=1e-8, max=1e8)
    prob = F.softmax(pair, dim=1)[:, 1, :].clone().view(n, k, h, w)
    decode = torch.sum(prob >= 0.5, dim=1).view(n, 1, h, w)
    return decode, prob


def released_loss(prob, gt, sid):
    """The released loss form (dense K×H×W labels, log of clamped P / 1 − P, masked mean),
    with the SPEC's SID labels (their swapped SID/uniform branches are not reproduced)."""
    n, _, h, w = gt.shape
    k = prob.shape[1]
    valid = gt > 0.0
    ord_c0 = torch.ones(n, k, h, w, device=gt.device)
    label = sid_labels(sid, gt)  # [N,1,H,W]
    mask = torch.linspace(0, k - 1, k, requires_grad=False).view(1, k, 1, 1).to(gt.device)
    mask = mask.repeat(n, 1, h, w).contiguous().long()
    mask = mask >= label  # k ≥ l → y_k = 0
    ord_c0[mask] = 0  # y_k = [k < l]
    ord_c1 = 1 - ord_c0
    logp = torch.log(torch.clamp(prob, min=1e-8))
    log1p = torch.log(torch.clamp(1 - prob, min=1e-8))
    entropy = torch.sum(ord_c0 * logp, dim=1) + torch.sum(ord_c1 * log1p, dim=1)
    return -entropy[valid.squeeze(1)].mean()


class Runner:
    """forward / decode / loss of one network with one ordinal mode, as bench model calls them."""

    def __init__(self, net, mode):
        self.net, self.cfg, self.mode = net, net.cfg, mode
        if self.cfg["head"] != "ordinal":
            self.mode = "regression"

    def forward(self, image, radar):
        """The head output `bench model` times as `forward`."""
        cfg, y = self.cfg, self.net(image, radar)
        if self.mode == "regression":
            return y
        if self.mode == "released":
            h, w = image.shape[-2:]
            up = F.interpolate(y, size=(h, w), mode="bilinear", align_corners=True)
            return released_ordinal_layer(up)
        if cfg["clamp_logits"]:  # DepthNet::forward_t with clamp_logits
            up = upsample(y, cfg["out_height"], cfg["out_width"], cfg["align_corners"])
            return pair_differences(up.clamp(1e-8, 1e8))
        return pair_differences(y)

    def decode(self, out, h, w):
        cfg, sid = self.cfg, self.cfg["sid"]
        if self.mode == "regression":
            return (upsample(out, h, w, cfg["align_corners"]).float()
                    - sid["decode_offset_m"]).clamp_min(0.0)
        return levels_to_depth(sid, self.levels(out, h, w))

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


def read_safetensors(path):
    """A safetensors file (what `VarStore::save` writes) → {name: tensor}, without the package."""
    import struct
    with open(path, "rb") as f:
        data = f.read()
    n = struct.unpack("<Q", data[:8])[0]
    header = json.loads(data[8:8 + n])
    dtypes = {"F32": torch.float32, "F64": torch.float64, "I64": torch.int64,
              "BF16": torch.bfloat16, "F16": torch.float16}
    out = {}
    for k, v in header.items():
        if k == "__metadata__":
            continue
        a, b = v["data_offsets"]
        buf = bytearray(data[8 + n + a:8 + n + b])
        t = torch.frombuffer(buf, dtype=dtypes[v["dtype"]]) if buf else \
            torch.empty(0, dtype=dtypes[v["dtype"]])
        out[k] = t.reshape(v["shape"])
    return out


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
    ours = read_safetensors(os.path.join(d, "weights.safetensors"))
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
    print(json.dumps(rep))
    return 0


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default="released",
                   help="released, paper or tiny; comma-separated for several (one process)")
    p.add_argument("--config-json", help="a ModelConfig JSON (`model-info --print-config`) "
                   "or a `model-info --json` report instead of --preset")
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
    p.add_argument("--warmup", type=int, default=3)
    p.add_argument("--repeats", type=int, default=10)
    p.add_argument("--cudnn-benchmark", default="true", choices=["true", "false"])
    p.add_argument("--threads", type=int, help="CPU threads (default: torch's choice)")
    p.add_argument("--params-only", action="store_true",
                   help="print {params, macs_per_image} (meta device, no allocation) and exit")
    p.add_argument("--out", help="write the JSON here (one object, or {\"runs\": [...]})")
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
    print(f"{'config':<9} {'ordinal':<16} {'prec':<5} cl {'fwd ms':>10} {'fwd+dec ms':>10} "
          f"{'train ms':>11} {'peak MiB':>9}", flush=True)
    for cfg in cfgs:
        for prec, cl in variants:
            for mode in modes:
                try:
                    r = bench(cfg, a, dev, prec, cl, mode, baseline)
                except torch.cuda.OutOfMemoryError as e:  # the released form at batch 8
                    r = {"config": cfg["name"], "ordinal": mode, "precision": prec,
                         "channels_last": cl, "implementation": "pytorch-eager",
                         "variant_requested": prec + ("-cl" if cl else ""),
                         "error": f"CUDA out of memory: {str(e)[:300]}"}
                    torch.cuda.empty_cache()
                    print(f"{cfg['name']:<9} {mode:<16} {prec:<5} {'cl' if cl else '  '} "
                          f"out of memory", flush=True)
                    runs.append(r)
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
