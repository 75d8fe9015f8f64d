# The authors' released architecture (SPEC §6.1) in plain PyTorch, for
# crates/checkpoint/tests/model/released_reference.rs: random weights (fixed seed, random BN statistics),
# `torch.save(model.state_dict())` with the authors' key names, and their inference
# conventions (ImageNet-normalised image, radar in metres, 2K logits bilinearly upsampled with
# align_corners=True, clamped to [1e-8, 1e8], pairwise softmax, count of P_k >= 0.5, SID bin
# centre - 0.3 m). Usage: python released_reference.py OUT_DIR CONFIG_JSON
import json
import math
import sys

try:
    import numpy as np
    import torch
    import torch.nn as nn
    import torch.nn.functional as F
except ImportError as e:  # the Rust test skips on exit code 77
    print(f"torch/numpy not importable: {e}", file=sys.stderr)
    sys.exit(77)

out, cfg = sys.argv[1], json.loads(sys.argv[2])
torch.manual_seed(cfg["seed"])
torch.set_num_threads(1)


# The module tree carries the attribute names of the authors' public code (MI-Hussain/RVMDE,
# model/rvmde.py and model/radar_retinanet.py, read for names and semantics only): the state-dict
# keys are therefore the ones `torch.save(RVMDE().state_dict())` writes, e.g.
# `retinanet.backbone.fpn.P3_1.weight`, `resnet_radar.backbone.conv4.weight` and
# `conv_radar.0.weight` — the 1x1 radar convolutions sit on the top-level network, not inside
# the radar backbone. Widths are parameters so that the test can run a narrow copy.


class Bottleneck(nn.Module):
    """ResNet v1.5 bottleneck (stride and dilation on the 3x3), `conv1..3`, `bn1..3`,
    optional `downsample` = Sequential(1x1 conv, BN)."""

    def __init__(self, cin, planes, stride=1, dilation=1):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, planes, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, stride, dilation, dilation, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = nn.Conv2d(planes, planes * 4, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(planes * 4)
        self.relu = nn.ReLU()
        self.downsample = None
        if stride != 1 or cin != planes * 4:
            self.downsample = nn.Sequential(
                nn.Conv2d(cin, planes * 4, 1, stride, bias=False), nn.BatchNorm2d(planes * 4)
            )

    def forward(self, x):
        y = self.relu(self.bn1(self.conv1(x)))
        y = self.relu(self.bn2(self.conv2(y)))
        y = self.bn3(self.conv3(y))
        r = x if self.downsample is None else self.downsample(x)
        return self.relu(y + r)


def make_layer(cin, planes, n, stride, dilation):
    blocks = [Bottleneck(cin, planes, stride, dilation)]
    blocks += [Bottleneck(planes * 4, planes, 1, dilation) for _ in range(n - 1)]
    return nn.Sequential(*blocks), planes * 4


class PyramidFeatures(nn.Module):
    """`P5_1`, `P5_2`, `P4_1`, `P4_2`, `P3_1`, `P3_2` (1x1 and 3x3 convs with bias)."""

    def __init__(self, c3, c4, c5, ch):
        super().__init__()
        self.P5_1 = nn.Conv2d(c5, ch, 1)
        self.P5_2 = nn.Conv2d(ch, ch, 3, padding=1)
        self.P4_1 = nn.Conv2d(c4, ch, 1)
        self.P4_2 = nn.Conv2d(ch, ch, 3, padding=1)
        self.P3_1 = nn.Conv2d(c3, ch, 1)
        self.P3_2 = nn.Conv2d(ch, ch, 3, padding=1)

    def forward(self, c3, c4, c5):
        t5 = self.P5_1(c5)
        t4 = self.P4_1(c4) + F.interpolate(t5, scale_factor=2, mode="nearest")
        t3 = self.P3_1(c3) + F.interpolate(t4, scale_factor=2, mode="nearest")
        return self.P3_2(t3), self.P4_2(t4), self.P5_2(t5)


class RetinaNet(nn.Module):
    """Image path (`retinanet.backbone`): deep stem, ResNet-101 body, FPN, `convfeat1..3`."""

    def __init__(self, w, blocks, ch):
        super().__init__()
        self.conv1 = nn.Conv2d(3, w, 3, 2, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(w)
        self.conv2 = nn.Conv2d(w, w, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(w)
        self.conv3 = nn.Conv2d(w, 2 * w, 3, 1, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(2 * w)
        self.relu = nn.ReLU()
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        self.convfeat1 = nn.Conv2d(ch, ch, 7, 4, 2, bias=False)
        self.convfeat2 = nn.Conv2d(ch, ch, 3, 2, 1, bias=False)
        self.convfeat3 = nn.Conv2d(ch, ch, 3, 1, 1, bias=False)
        c = 2 * w
        self.layer1, c1 = make_layer(c, w, blocks[0], 1, 1)
        self.layer2, c2 = make_layer(c1, 2 * w, blocks[1], 2, 1)
        self.layer3, c3 = make_layer(c2, 4 * w, blocks[2], 2, 1)
        self.layer4, c4 = make_layer(c3, 8 * w, blocks[3], 2, 1)
        self.fpn = PyramidFeatures(c2, c3, c4, ch)

    def forward(self, x):
        x = self.relu(self.bn1(self.conv1(x)))
        x = self.relu(self.bn2(self.conv2(x)))
        x = self.relu(self.bn3(self.conv3(x)))
        x = self.maxpool(x)
        c1 = self.layer1(x)
        c2 = self.layer2(c1)
        c3 = self.layer3(c2)
        c4 = self.layer4(c3)
        p3, p4, p5 = self.fpn(c2, c3, c4)
        f1 = self.relu(self.convfeat1(p3))
        f2 = self.relu(self.convfeat2(p4))
        f3 = self.relu(self.convfeat3(p5))
        return torch.cat([f1, f2, f3], 1)


class ResNet(nn.Module):
    """Radar path (`resnet_radar.backbone`): stem `conv1..4` / `bn1..4`, 7x7/4 max-pool,
    four layers of 2 bottlenecks (strides 1/2/1/1, dilations 1/1/2/4)."""

    def __init__(self, w, cin):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, w, 3, 2, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(w)
        self.conv2 = nn.Conv2d(w, w, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(w)
        self.conv3 = nn.Conv2d(w, w, 3, 1, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(w)
        self.conv4 = nn.Conv2d(w, 2 * w, 7, 2, 3, bias=False)
        self.bn4 = nn.BatchNorm2d(2 * w)
        self.relu = nn.ReLU()
        self.maxpool = nn.MaxPool2d(7, 4, 1)
        c = 2 * w
        self.layer1, c = make_layer(c, w, 2, 1, 1)
        self.layer2, c = make_layer(c, 2 * w, 2, 2, 1)
        self.layer3, c = make_layer(c, 4 * w, 2, 1, 2)
        self.layer4, c = make_layer(c, 8 * w, 2, 1, 4)
        self.out_channels = c

    def forward(self, x):
        for conv, bn in [(self.conv1, self.bn1), (self.conv2, self.bn2),
                         (self.conv3, self.bn3), (self.conv4, self.bn4)]:
            x = self.relu(bn(conv(x)))
        x = self.maxpool(x)
        return self.layer4(self.layer3(self.layer2(self.layer1(x))))


class ResNet102(nn.Module):
    def __init__(self, c):
        super().__init__()
        self.backbone = RetinaNet(c["width"], c["blocks"], c["decoder_channels"])


class ResNet_radar(nn.Module):
    def __init__(self, c):
        super().__init__()
        self.backbone = ResNet(c["radar_width"], c["radar_channels"])


class RVMDE(nn.Module):
    """The released network: `retinanet`, `resnet_radar`, `conv_radar` (1x1 + ReLU twice, on
    the top level), `concat_process` (Dropout2d, 1x1, ReLU, Dropout2d, 1x1 to 2K)."""

    def __init__(self, c):
        super().__init__()
        self.retinanet = ResNet102(c)
        self.resnet_radar = ResNet_radar(c)
        r = c["radar_out_channels"]
        self.conv_radar = nn.Sequential(
            nn.Conv2d(self.resnet_radar.backbone.out_channels, r, 1), nn.ReLU(),
            nn.Conv2d(r, r, 1), nn.ReLU(),
        )
        fused = 3 * c["decoder_channels"] + r
        self.concat_process = nn.Sequential(
            nn.Dropout2d(0.5),
            nn.Conv2d(fused, c["head_channels"], 1),
            nn.ReLU(),
            nn.Dropout2d(0.5),
            nn.Conv2d(c["head_channels"], 2 * c["bins"], 1),
        )
        self.size = (c["height"], c["width_px"])

    def forward(self, image, radar):
        img = self.retinanet.backbone(image)
        rad = self.conv_radar(self.resnet_radar.backbone(radar))
        y = self.concat_process(torch.cat([img, rad], 1))
        return F.interpolate(y, size=self.size, mode="bilinear", align_corners=True)


def ordinal(y):
    """DORN-style ordinal layer as the released code has it (clamp before the softmax)."""
    n, c, h, w = y.size()
    k = c // 2
    a = y[:, ::2, :, :].clone().view(n, 1, k * h * w)
    b = y[:, 1::2, :, :].clone().view(n, 1, k * h * w)
    pair = torch.clamp(torch.cat((a, b), dim=1), min=1e-8, max=1e8)
    p1 = F.softmax(pair, dim=1)[:, 1, :].clone().view(n, k, h, w)
    return torch.sum(p1 >= 0.5, dim=1)  # [N,H,W] levels


model = RVMDE(cfg)
g = cfg["bn_spread"]
for m in model.modules():
    if isinstance(m, nn.BatchNorm2d):
        with torch.no_grad():
            m.weight.uniform_(1 - g, 1 + g)
            m.bias.uniform_(-g, g)
            m.running_mean.uniform_(-g, g)
            m.running_var.uniform_(1 - g, 1 + 2 * g)
            m.num_batches_tracked.fill_(1000)
# The last conv's weights scaled so that the logit pairs vary across pixels and bins.
with torch.no_grad():
    model.concat_process[4].weight.mul_(cfg["head_gain"])
model.eval()
if cfg.get("fill") == "distinct":
    # Weight import by value (crates/checkpoint/tests/model/import_by_value.rs): state-dict entry j holds
    # j + 1 + (i mod 4096)/8192 at flat index i — exact in float32, different for every tensor,
    # so a swap of two same-shaped tensors or a transposed copy cannot go unseen.
    sd = model.state_dict()
    with torch.no_grad():
        for j, (k, v) in enumerate(sd.items()):
            if v.is_floating_point():
                i = torch.arange(v.numel(), dtype=torch.float64)
                v.copy_((j + 1 + torch.remainder(i, 4096) / 8192).view(v.shape))
    torch.save(sd, f"{out}/weights.pth")
    with open(f"{out}/keys.json", "w") as f:
        json.dump([[k, list(v.shape)] for k, v in sd.items()], f)
    print(json.dumps({"keys": len(sd), "torch": torch.__version__}))
    sys.exit(0)
torch.save(model.state_dict(), f"{out}/weights.pth")

h, w = cfg["height"], cfg["width_px"]
if "rgb_file" in cfg:
    # A real sample: RGB in [0, 1] and the radar maps in metres, as depthsense feeds them.
    rgb = torch.from_numpy(np.fromfile(cfg["rgb_file"], dtype="<f4").reshape(1, 3, h, w))
    radar = torch.from_numpy(
        np.fromfile(cfg["radar_file"], dtype="<f4").reshape(1, cfg["radar_channels"], h, w))
else:
    rgb = torch.randint(0, 256, (1, 3, h, w)).float() / 255.0
    # Smooth the image a little so that the features have spatial structure.
    rgb = F.avg_pool2d(rgb, 5, 1, 2)
    radar = torch.zeros(1, cfg["radar_channels"], h, w)
    for _ in range(cfg["radar_strips"]):  # height-extended-like vertical strips, metres
        u = int(torch.randint(0, w, ()))
        v0 = int(torch.randint(0, h - 8, ()))
        ln = int(torch.randint(3, h // 2, ()))
        radar[:, :, v0:v0 + ln, u] = float(torch.rand(()) * 55 + 5)
# The authors' loader normalises with the ImageNet statistics; radar stays in metres.
mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
image = (rgb - mean) / std

with torch.no_grad():
    levels = ordinal(model(image, radar))
step = math.log(cfg["beta"] / cfg["alpha"]) / cfg["bins"]
lv = levels.double()
depth = ((torch.exp(lv * step + math.log(cfg["alpha"])) +
          torch.exp((lv + 1) * step + math.log(cfg["alpha"]))) / 2 - cfg["decode_offset"])

image.numpy().astype("<f4").tofile(f"{out}/image.f32")
radar.numpy().astype("<f4").tofile(f"{out}/radar.f32")
levels.numpy().astype("<i8").tofile(f"{out}/levels.i64")
depth.numpy().astype("<f4").tofile(f"{out}/depth.f32")
with open(f"{out}/keys.json", "w") as f:
    json.dump({k: list(v.shape) for k, v in model.state_dict().items()}, f)
print(json.dumps({"distinct_levels": int(levels.unique().numel()),
                  "keys": len(model.state_dict()), "torch": torch.__version__}))
