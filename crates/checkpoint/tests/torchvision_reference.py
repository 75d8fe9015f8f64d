# An ImageNet ResNet state dict with torchvision's key names, for
# crates/checkpoint/tests/model/import_by_value.rs. The module tree carries the attribute names of
# torchvision's public `torchvision/models/resnet.py` (read for names only): `conv1`, `bn1`,
# `layer1..4` of `BasicBlock` (`conv1`, `bn1`, `conv2`, `bn2`, `downsample` = Sequential(1x1 conv,
# BN)) or `Bottleneck` (`conv1..3`, `bn1..3`, `downsample`, stride on the 3x3), `fc`. Widths are
# a parameter (torchvision's are 64) so that the test stays small. State-dict entry j holds
# j + 1 + (i mod 4096)/8192 at flat index i: exact in float32 and different for every tensor.
# Usage: python torchvision_reference.py OUT_DIR CONFIG_JSON ({"depth": 18|34|50|101, "width": w})
import json
import sys

try:
    import torch
    import torch.nn as nn
except ImportError as e:  # the Rust test reports this (a failure under DEPTHSENSE_REQUIRE_TORCH=1)
    print(f"torch not importable: {e}", file=sys.stderr)
    sys.exit(77)

out, cfg = sys.argv[1], json.loads(sys.argv[2])


def conv3x3(cin, cout, stride=1):
    return nn.Conv2d(cin, cout, 3, stride, 1, bias=False)


def conv1x1(cin, cout, stride=1):
    return nn.Conv2d(cin, cout, 1, stride, bias=False)


class BasicBlock(nn.Module):
    expansion = 1

    def __init__(self, cin, planes, stride=1, downsample=None):
        super().__init__()
        self.conv1 = conv3x3(cin, planes, stride)
        self.bn1 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = conv3x3(planes, planes)
        self.bn2 = nn.BatchNorm2d(planes)
        self.downsample = downsample


class Bottleneck(nn.Module):
    expansion = 4

    def __init__(self, cin, planes, stride=1, downsample=None):
        super().__init__()
        self.conv1 = conv1x1(cin, planes)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = conv3x3(planes, planes, stride)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = conv1x1(planes, planes * 4)
        self.bn3 = nn.BatchNorm2d(planes * 4)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = downsample


class ResNet(nn.Module):
    def __init__(self, block, layers, w):
        super().__init__()
        self.inplanes = w
        self.conv1 = nn.Conv2d(3, w, 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(w)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        self.layer1 = self._make_layer(block, w, layers[0])
        self.layer2 = self._make_layer(block, 2 * w, layers[1], 2)
        self.layer3 = self._make_layer(block, 4 * w, layers[2], 2)
        self.layer4 = self._make_layer(block, 8 * w, layers[3], 2)
        self.avgpool = nn.AdaptiveAvgPool2d((1, 1))
        self.fc = nn.Linear(8 * w * block.expansion, 1000)

    def _make_layer(self, block, planes, blocks, stride=1):
        downsample = None
        if stride != 1 or self.inplanes != planes * block.expansion:
            downsample = nn.Sequential(
                conv1x1(self.inplanes, planes * block.expansion, stride),
                nn.BatchNorm2d(planes * block.expansion),
            )
        layers = [block(self.inplanes, planes, stride, downsample)]
        self.inplanes = planes * block.expansion
        layers += [block(self.inplanes, planes) for _ in range(1, blocks)]
        return nn.Sequential(*layers)


LAYOUTS = {18: (BasicBlock, [2, 2, 2, 2]), 34: (BasicBlock, [3, 4, 6, 3]),
           50: (Bottleneck, [3, 4, 6, 3]), 101: (Bottleneck, [3, 4, 23, 3])}
block, layers = LAYOUTS[cfg["depth"]]
model = ResNet(block, layers, cfg["width"])
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
