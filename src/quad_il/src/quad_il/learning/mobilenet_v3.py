"""MobileNetV3 depth backbone, written in the project with torchvision's module layout and parameter names.

Architecture after Howard et al., "Searching for MobileNetV3" (ICCV 2019), Tables 1 (Large) and 2 (Small):
inverted-residual blocks (1x1 expansion, depthwise kxk, optional squeeze-and-excitation, 1x1 linear
projection) with ReLU or hard-swish, a 1x1 conv to 6x the last block's width, global average pooling and a
two-layer classifier. torchvision cannot be installed beside this torch (docs/learning.md), so the network is
written here; module names and nesting follow torchvision's `mobilenet_v3_small`/`mobilenet_v3_large` exactly
(`features.<i>.block.<j>...`, `classifier.0/3`), so a torchvision ImageNet state dict loads with
`load_torchvision_state_dict` (the 3-channel stem is folded to the depth image's channel count).

Initialisation is random (torchvision's scheme: Kaiming-normal fan-out convs, unit BN, N(0, 0.01) linears).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor, nn

Variant = Literal["small", "large"]

# BatchNorm settings of the reference implementation (TF's MobileNetV3: eps 1e-3, decay 0.99).
_BN_EPS = 1e-3
_BN_MOMENTUM = 0.01


def make_divisible(value: float, divisor: int = 8) -> int:
    """Round a channel count to a multiple of `divisor`, never more than 10 % below `value` (paper's rule)."""
    rounded = max(divisor, int(value + divisor / 2) // divisor * divisor)
    if rounded < 0.9 * value:
        rounded += divisor
    return rounded


@dataclass(frozen=True)
class BlockSpec:
    """One bneck row of the paper's tables."""

    in_channels: int
    kernel: int
    expanded_channels: int
    out_channels: int
    use_se: bool
    hard_swish: bool
    stride: int


def _b(i: int, k: int, e: int, o: int, se: bool, act: str, s: int) -> BlockSpec:
    return BlockSpec(i, k, e, o, se, act == "HS", s)


# Table 1 of the paper (MobileNetV3-Large), width multiplier 1.0.
LARGE_BLOCKS: tuple[BlockSpec, ...] = (
    _b(16, 3, 16, 16, False, "RE", 1),
    _b(16, 3, 64, 24, False, "RE", 2),
    _b(24, 3, 72, 24, False, "RE", 1),
    _b(24, 5, 72, 40, True, "RE", 2),
    _b(40, 5, 120, 40, True, "RE", 1),
    _b(40, 5, 120, 40, True, "RE", 1),
    _b(40, 3, 240, 80, False, "HS", 2),
    _b(80, 3, 200, 80, False, "HS", 1),
    _b(80, 3, 184, 80, False, "HS", 1),
    _b(80, 3, 184, 80, False, "HS", 1),
    _b(80, 3, 480, 112, True, "HS", 1),
    _b(112, 3, 672, 112, True, "HS", 1),
    _b(112, 5, 672, 160, True, "HS", 2),
    _b(160, 5, 960, 160, True, "HS", 1),
    _b(160, 5, 960, 160, True, "HS", 1),
)
# Table 2 of the paper (MobileNetV3-Small).
SMALL_BLOCKS: tuple[BlockSpec, ...] = (
    _b(16, 3, 16, 16, True, "RE", 2),
    _b(16, 3, 72, 24, False, "RE", 2),
    _b(24, 3, 88, 24, False, "RE", 1),
    _b(24, 5, 96, 40, True, "HS", 2),
    _b(40, 5, 240, 40, True, "HS", 1),
    _b(40, 5, 240, 40, True, "HS", 1),
    _b(40, 5, 120, 48, True, "HS", 1),
    _b(48, 5, 144, 48, True, "HS", 1),
    _b(48, 5, 288, 96, True, "HS", 2),
    _b(96, 5, 576, 96, True, "HS", 1),
    _b(96, 5, 576, 96, True, "HS", 1),
)
# Width of the classifier's hidden layer ("NBN" 1x1 conv in the paper, a Linear in torchvision).
LAST_CHANNEL: dict[str, int] = {"small": 1024, "large": 1280}
BLOCKS: dict[str, tuple[BlockSpec, ...]] = {"small": SMALL_BLOCKS, "large": LARGE_BLOCKS}


class ConvNormActivation(nn.Sequential):
    """Conv2d (no bias) -> BatchNorm2d -> optional activation; indices 0/1/2 as torchvision's."""

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int,
        stride: int = 1,
        groups: int = 1,
        activation: type[nn.Module] | None = nn.ReLU,
    ) -> None:
        layers: list[nn.Module] = [
            nn.Conv2d(
                in_channels,
                out_channels,
                kernel_size,
                stride,
                padding=(kernel_size - 1) // 2,
                groups=groups,
                bias=False,
            ),
            nn.BatchNorm2d(out_channels, eps=_BN_EPS, momentum=_BN_MOMENTUM),
        ]
        if activation is not None:
            layers.append(activation())
        super().__init__(*layers)


class SqueezeExcitation(nn.Module):
    """Squeeze-and-excitation as in the paper: squeeze to 1/4 (rounded to 8), ReLU, hard-sigmoid gate."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        squeeze = make_divisible(channels // 4, 8)
        self.avgpool = nn.AdaptiveAvgPool2d(1)
        self.fc1 = nn.Conv2d(channels, squeeze, 1)
        self.activation = nn.ReLU()
        self.fc2 = nn.Conv2d(squeeze, channels, 1)
        self.scale_activation = nn.Hardsigmoid()

    def forward(self, x: Tensor) -> Tensor:
        scale = self.scale_activation(self.fc2(self.activation(self.fc1(self.avgpool(x)))))
        return scale * x


class InvertedResidual(nn.Module):
    """bneck: [1x1 expand] -> depthwise kxk -> [SE] -> 1x1 linear projection; residual when shapes allow."""

    def __init__(self, spec: BlockSpec) -> None:
        super().__init__()
        if spec.stride not in (1, 2):
            raise ValueError(f"MobileNetV3 block stride must be 1 or 2, got {spec.stride}")
        act: type[nn.Module] = nn.Hardswish if spec.hard_swish else nn.ReLU
        layers: list[nn.Module] = []
        if spec.expanded_channels != spec.in_channels:
            layers.append(ConvNormActivation(spec.in_channels, spec.expanded_channels, 1, activation=act))
        layers.append(
            ConvNormActivation(
                spec.expanded_channels,
                spec.expanded_channels,
                spec.kernel,
                stride=spec.stride,
                groups=spec.expanded_channels,
                activation=act,
            )
        )
        if spec.use_se:
            layers.append(SqueezeExcitation(spec.expanded_channels))
        layers.append(ConvNormActivation(spec.expanded_channels, spec.out_channels, 1, activation=None))
        self.block = nn.Sequential(*layers)
        self.use_res_connect: bool = spec.stride == 1 and spec.in_channels == spec.out_channels

    def forward(self, x: Tensor) -> Tensor:
        y = self.block(x)
        if self.use_res_connect:
            y = y + x
        return y


class MobileNetV3(nn.Module):
    """MobileNetV3-Small/Large: (B, in_channels, H, W) -> (B, num_classes) logits (no activation)."""

    def __init__(
        self, variant: Variant = "small", in_channels: int = 1, num_classes: int = 1000, dropout: float = 0.2
    ) -> None:
        super().__init__()
        if variant not in BLOCKS:
            raise ValueError(f"MobileNetV3 variant must be 'small' or 'large', got {variant!r}")
        if in_channels < 1 or num_classes < 1:
            raise ValueError(f"in_channels and num_classes must be >= 1, got {in_channels}, {num_classes}")
        if not 0.0 <= dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {dropout}")
        self.variant = variant
        self.in_channels = in_channels
        blocks = BLOCKS[variant]
        layers: list[nn.Module] = [
            ConvNormActivation(in_channels, blocks[0].in_channels, 3, stride=2, activation=nn.Hardswish)
        ]
        layers += [InvertedResidual(spec) for spec in blocks]
        last_conv = 6 * blocks[-1].out_channels
        layers.append(ConvNormActivation(blocks[-1].out_channels, last_conv, 1, activation=nn.Hardswish))
        self.features = nn.Sequential(*layers)
        self.avgpool = nn.AdaptiveAvgPool2d(1)
        self.classifier = nn.Sequential(
            nn.Linear(last_conv, LAST_CHANNEL[variant]),
            nn.Hardswish(),
            nn.Dropout(p=dropout),
            nn.Linear(LAST_CHANNEL[variant], num_classes),
        )
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """torchvision's initialisation (uses the global torch RNG: seed it first)."""
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out")
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
            elif isinstance(m, nn.Linear):
                nn.init.normal_(m.weight, 0.0, 0.01)
                nn.init.zeros_(m.bias)

    def forward(self, x: Tensor) -> Tensor:
        x = self.features(x)
        x = torch.flatten(self.avgpool(x), 1)
        return self.classifier(x)

    def load_torchvision_state_dict(
        self, state_dict: Mapping[str, Tensor], load_classifier: bool = True
    ) -> None:
        """Load a torchvision `mobilenet_v3_<variant>` state dict (e.g. its ImageNet weights file).

        The stem conv of a 3-channel (RGB) state dict is adapted to this network's input channels: for one
        depth channel the three filters are summed, which gives the same response to a grey image (R = G = B)
        as the RGB network. With `load_classifier=False` the final 1000-way layer keeps its initialisation
        (for a different `num_classes`). Raises ValueError naming missing, unexpected or mis-shaped keys.
        """
        own = self.state_dict()
        adapted: dict[str, Tensor] = {}
        for key, value in state_dict.items():
            if not load_classifier and key.startswith("classifier.3."):
                continue
            if key == "features.0.0.weight" and value.dim() == 4 and value.shape[1] != self.in_channels:
                value = adapt_stem_channels(value, self.in_channels)
            adapted[key] = value
        expected = {k for k in own if load_classifier or not k.startswith("classifier.3.")}
        missing = sorted(expected - adapted.keys())
        unexpected = sorted(adapted.keys() - own.keys())
        if missing or unexpected:
            raise ValueError(
                f"state dict does not match torchvision mobilenet_v3_{self.variant}: "
                f"missing keys {missing[:8]}{' ...' if len(missing) > 8 else ''} ({len(missing)}), "
                f"unexpected keys {unexpected[:8]}{' ...' if len(unexpected) > 8 else ''} ({len(unexpected)})"
            )
        bad = [
            f"{k}: file {tuple(v.shape)} vs model {tuple(own[k].shape)}"
            for k, v in adapted.items()
            if tuple(v.shape) != tuple(own[k].shape)
        ]
        if bad:
            raise ValueError(f"state dict shapes do not match mobilenet_v3_{self.variant}: {bad[:8]}")
        self.load_state_dict(adapted, strict=load_classifier)


def adapt_stem_channels(weight: Tensor, in_channels: int) -> Tensor:
    """Stem conv weight (O, C, k, k) -> (O, in_channels, k, k).

    One channel: the sum over C (exact for inputs that are equal in every channel). More channels: the mean
    filter repeated and scaled by C / in_channels, which keeps the response to a constant-across-channels
    input.
    """
    if in_channels == 1:
        return weight.sum(dim=1, keepdim=True)
    mean = weight.mean(dim=1, keepdim=True)
    return mean.repeat(1, in_channels, 1, 1) * (weight.shape[1] / in_channels)


def count_parameters(module: nn.Module) -> int:
    """Number of trainable parameters (BatchNorm running statistics excluded, as in torchvision's tables)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)
