"""depthsense's networks in plain PyTorch: one file, no dependency but torch.

Every preset and option of depthsense's `ModelConfig` (crates/model/src/config.rs), layer for
layer as crates/model/src/{encoder,decoder,radar_branch,fusion,head,net}.rs build them: the
same modules in the same order, the same strides, paddings, dilations and initialisation rules,
and module attribute names equal to depthsense's variable names, so that `state_dict()` keys
are depthsense's checkpoint keys (`rgb.layer1.0.conv1.weight`, …; PyTorch's extra
`num_batches_tracked` buffers aside).

    import depthsense_torch as dt
    cfg = dt.PRESETS["tiny"]()                  # or dt.load_config(None, "config.json")
    net = dt.DepthNet(cfg).eval()
    y = net(image, radar)                       # image [N,3,H,W] normalised, radar [N,C,H,W]

Configurations are plain dicts with depthsense's serde field names (`model-info
--print-config` / `--json` writes them). Used by scripts/torch_reference.py (the PyTorch side of
`depthsense bench model`'s comparison) and checked against depthsense by
crates/checkpoint/tests/model/torch_reference_params.rs: equal parameter counts and multiply-adds for every
preset, equal head outputs with depthsense's weights.
"""

import json
import math

import torch
import torch.nn as nn
import torch.nn.functional as F


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


def tiny_wide():
    """The demo's and the experiments' preset (`ModelConfig::tiny_wide`): tiny's layout at the
    widths of a ResNet-34; the head dropout stays tiny's."""
    c = tiny()
    c.update({
        "name": "tiny-wide",
        "backbone_depth": 34,
        "backbone_width": 64,
        "decoder_channels": 128,
        "head_channels": 128,
        "radar_width": 32,
        "radar_out_channels": 256,
    })
    return c


PRESETS = {"paper": paper, "released": released, "tiny": tiny, "tiny-wide": tiny_wide}


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
# (`--check`, crates/checkpoint/tests/model/torch_reference_params.rs).

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
    """`net::pool_nearest`: the nearest non-zero depth of each k cell (max-pool of 1/d).
    Computed in float32 whatever `d`'s precision (1/1e-6 and 1e-12 are out of half's range),
    returned in `d`'s dtype."""
    d32 = d.float()
    inv = d32.clamp_min(1e-6).reciprocal() * (d32 > 0).float()
    inv = F.max_pool2d(inv, k, k, 0, ceil_mode=ceil_mode)
    return (inv.clamp_min(1e-12).reciprocal() * (inv > 0).float()).to(d.dtype)


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


# --------------------------------------------------------------------------------------------
# The deployment contract and depthsense checkpoints

# `depthsense_data::IMAGENET_MEAN` / `IMAGENET_STD`: the image normalisation of SPEC §3.
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def head_output(net, image, radar):
    """`DepthNet::forward_t`: [N,2K,h,w] logits → [N,K,h,w] ordinal differences z (or, with
    `clamp_logits`, the 2K logits upsampled to out_height × out_width, clamped to [1e-8, 1e8],
    then paired); [N,1,h,w] metres for the L1 / L2 heads."""
    # The head's output in float32 whatever the network's precision: the clamp to [1e-8, 1e8]
    # and the decode are outside half's range (export --precision fp16).
    cfg, y = net.cfg, net(image, radar).float()
    if cfg["head"] != "ordinal":
        return y
    if cfg["clamp_logits"]:
        up = upsample(y, cfg["out_height"], cfg["out_width"], cfg["align_corners"])
        return pair_differences(up.clamp(1e-8, 1e8))
    return pair_differences(y)


def decode(cfg, out, h, w):
    """`DepthNet::decode_to`: a head output → depth [N,1,h,w] in metres. Ordinal: level
    l = Σ_k [z_k ≥ 0] after bilinear upsampling, depth = the SID bin's centre (SPEC §7);
    regression: the upsampled metres minus the decode offset, at least 0."""
    sid, ac = cfg["sid"], cfg["align_corners"]
    if cfg["head"] != "ordinal":
        return (upsample(out, h, w, ac).float() - sid["decode_offset_m"]).clamp_min(0.0)
    levels = (upsample(out, h, w, ac) >= 0).sum(1, keepdim=True)
    return levels_to_depth(sid, levels)


class DepthSense(nn.Module):
    """A depthsense network as `depthsense predict` runs it (docs/guide/deploy.md): `forward(image, radar)` with image [N,3,H,W] RGB in [0, 1] (the ImageNet
    normalisation and any input downscaling happen inside) and radar [N,C,H,W] in metres (the
    maps `predict` feeds, C = `radar_channels`; None for an RGB-only network) → depth
    [N,1,out_height,out_width] in metres. `self.net` is the `DepthNet`; its `state_dict()` keys
    are depthsense's checkpoint names."""

    def __init__(self, cfg):
        super().__init__()
        self.cfg = cfg
        self.net = DepthNet(cfg)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def forward(self, image, radar=None):
        cfg = self.cfg
        x = (image - self.mean) / self.std
        if radar is None:
            n, _, h, w = image.shape
            radar = image.new_zeros((n, cfg["radar_channels"], h, w))
        out = head_output(self.net, x, radar)
        return decode(cfg, out, cfg["out_height"], cfg["out_width"])


def read_safetensors(path):
    """A safetensors file → ({name: tensor}, metadata dict), without the safetensors package."""
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
    return out, header.get("__metadata__", {})


def load_checkpoint(path):
    """A depthsense checkpoint (`RUN/best.safetensors`: the weights under depthsense's names,
    the model config in the metadata) → a `DepthSense` module in eval mode."""
    tensors, meta = read_safetensors(path)
    if meta.get("format") != "depthsense-checkpoint-v1":
        raise ValueError(f"{path}: not a depthsense checkpoint (format {meta.get('format')!r})")
    cfg = json.loads(meta["depthsense.config"])
    for k, v in SERDE_DEFAULTS.items():
        cfg.setdefault(k, v)
    model = DepthSense(cfg)
    missing, unexpected = model.net.load_state_dict(tensors, strict=False)
    missing = [k for k in missing if not k.endswith("num_batches_tracked")]
    if missing or unexpected:
        raise ValueError(f"{path}: does not fit the config: missing {missing[:5]}, "
                         f"unexpected {unexpected[:5]}")
    return model.eval()

