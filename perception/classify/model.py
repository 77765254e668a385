"""ResNet18 (He et al. 2016), defined here because torchvision is not a dependency.

The network is the standard ImageNet ResNet18 (7x7 stem, max pool, four stages of two
basic blocks, global average pool, one linear layer) with two knobs the benchmarks
sweep: ``in_channels`` (1 for depth or IR, 2 for both) and ``width``, a multiplier on
every stage's channel count (1.0 is the paper's network, 0.5 "half width" costs about a
quarter of the arithmetic).
"""

from __future__ import annotations

import torch
from torch import nn

STAGE_CHANNELS = (64, 128, 256, 512)
BLOCKS_PER_STAGE = 2


def stage_channels(width: float) -> tuple[int, ...]:
    """Channel count of each stage for a width multiplier (at least 4 per stage).

    Raises:
        ValueError: ``width`` is not > 0.
    """
    if not width > 0:
        raise ValueError(f"width must be > 0, got {width}")
    return tuple(max(4, round(c * width)) for c in STAGE_CHANNELS)


class BasicBlock(nn.Module):
    """Two 3x3 convolutions with batch norm and an identity (or 1x1 projected) shortcut."""

    def __init__(self, in_ch: int, out_ch: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(in_ch, out_ch, 3, stride=stride, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(out_ch)
        self.conv2 = nn.Conv2d(out_ch, out_ch, 3, stride=1, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(out_ch)
        self.relu = nn.ReLU(inplace=True)
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or in_ch != out_ch:
            self.shortcut = nn.Sequential(
                nn.Conv2d(in_ch, out_ch, 1, stride=stride, bias=False), nn.BatchNorm2d(out_ch)
            )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        result: torch.Tensor = self.relu(out + self.shortcut(x))
        return result


class ResNet18(nn.Module):
    """ResNet18 for ``in_channels``-channel images of any size >= 32 px.

    Args:
        num_classes: size of the output logits.
        in_channels: input channels (1 = depth or IR, 2 = both).
        width: multiplier on the channels of every stage (1.0 = the standard network).
        input_px: if given, the network holds a mean input image ``(in_channels,
            input_px, input_px)`` (a buffer, zero until training sets it, saved with the
            weights) and subtracts it first: the bubbles' rest shape and shading are the
            same in every frame, so what is left is what the object did to them.
    """

    input_mean: torch.Tensor  # a buffer (register_buffer below)

    def __init__(
        self,
        num_classes: int,
        in_channels: int = 1,
        width: float = 1.0,
        input_px: int | None = None,
    ) -> None:
        super().__init__()
        if num_classes < 2:
            raise ValueError(f"num_classes must be >= 2, got {num_classes}")
        if in_channels < 1:
            raise ValueError(f"in_channels must be >= 1, got {in_channels}")
        channels = stage_channels(width)
        mean_shape = (in_channels, input_px, input_px) if input_px else (in_channels, 1, 1)
        self.register_buffer("input_mean", torch.zeros(mean_shape))
        self.stem = nn.Sequential(
            nn.Conv2d(in_channels, channels[0], 7, stride=2, padding=3, bias=False),
            nn.BatchNorm2d(channels[0]),
            nn.ReLU(inplace=True),
            nn.MaxPool2d(3, stride=2, padding=1),
        )
        layers: list[nn.Module] = []
        in_ch = channels[0]
        for index, out_ch in enumerate(channels):
            for block in range(BLOCKS_PER_STAGE):
                stride = 2 if index > 0 and block == 0 else 1
                layers.append(BasicBlock(in_ch, out_ch, stride))
                in_ch = out_ch
        self.stages = nn.Sequential(*layers)
        self.pool = nn.AdaptiveAvgPool2d(1)
        self.fc = nn.Linear(in_ch, num_classes)
        self._init_weights()

    def _init_weights(self) -> None:
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(module, nn.BatchNorm2d):
                nn.init.ones_(module.weight)
                nn.init.zeros_(module.bias)
        # Zero the last norm of each residual branch: every block starts as the identity,
        # which makes short SGD runs on small data markedly more stable (Goyal et al. 2017).
        for module in self.modules():
            if isinstance(module, BasicBlock):
                nn.init.zeros_(module.bn2.weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits ``(N, num_classes)`` for images ``(N, in_channels, H, W)``."""
        x = self.stages(self.stem(x - self.input_mean))
        logits: torch.Tensor = self.fc(torch.flatten(self.pool(x), 1))
        return logits


def parameter_count(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
