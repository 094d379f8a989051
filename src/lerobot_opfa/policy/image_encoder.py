"""The policy's RGB encoder: a convolutional backbone, spatial-softmax keypoints and a projection, one
encoder shared by every camera (as LeRobot's diffusion policy: Chi et al., RSS 2023).

Backbones: `resnet18`, torchvision's ResNet-18 (what LeRobot's diffusion policy uses): from scratch with
GroupNorm in place of BatchNorm, or with torchvision's weights where they are installed (its BatchNorm kept,
as the weights were trained with it); and `small`, four 3x3 convolutions with GroupNorm down to an eighth of
the image: a fraction of the ResNet's operations, what a CPU trains in minutes, and a finer map for the
keypoints than the ResNet's thirty-second (docs/results.md, "Datasets as a rig records them").
"""

from __future__ import annotations

from types import MappingProxyType

import torch
from torch import Tensor, nn

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class SpatialSoftmax(nn.Module):
    """(B, C, H, W) feature maps -> (B, K, 2) expected image coordinates of K learned keypoints (Levine et
    al., 2016): where things are, which a diffusion policy reads far better than pooled features."""

    def __init__(self, channels: int, height: int, width: int, keypoints: int):
        super().__init__()
        self.to_keypoints = nn.Conv2d(channels, keypoints, kernel_size=1)
        ys, xs = torch.meshgrid(torch.linspace(-1, 1, height), torch.linspace(-1, 1, width), indexing="ij")
        self.register_buffer("grid", torch.stack([xs.flatten(), ys.flatten()], dim=-1), persistent=False)

    def forward(self, features: Tensor) -> Tensor:
        logits = self.to_keypoints(features).flatten(2)  # (B, K, H*W)
        return torch.softmax(logits, dim=-1) @ self.grid


def _group_norm(channels: int) -> nn.GroupNorm:
    return nn.GroupNorm(max(1, channels // 16), channels)


def small_backbone(widths: tuple[int, ...] = (32, 64, 128, 128), strides: tuple[int, ...] = (2, 2, 2, 1)):
    """3x3 convolutions with GroupNorm and ReLU, down to an eighth of the image: a feature map fine enough
    for keypoints to place a small object to a few pixels."""
    layers: list[nn.Module] = []
    channels = 3
    for width, stride in zip(widths, strides, strict=True):
        layers += [nn.Conv2d(channels, width, 3, stride=stride, padding=1), _group_norm(width), nn.ReLU()]
        channels = width
    return nn.Sequential(*layers)


def resnet18_backbone(weights: str | None) -> nn.Sequential:
    """torchvision's ResNet-18 up to its last residual stage. From scratch, BatchNorm is replaced by
    GroupNorm: batch statistics of a small batch of correlated frames make a poor normaliser."""
    import torchvision

    try:
        net = torchvision.models.resnet18(weights=weights)
    except Exception as error:  # noqa: BLE001 - torchvision's download error names no fix
        raise ValueError(
            f"--policy.image_backbone_weights={weights}: torchvision could not load them ({error}); leave "
            "the flag out to train the backbone from scratch"
        ) from None

    def swap(module: nn.Module) -> None:
        for name, child in module.named_children():
            if isinstance(child, nn.BatchNorm2d):
                setattr(module, name, _group_norm(child.num_features))
            else:
                swap(child)

    if weights is None:
        swap(net)
    return nn.Sequential(*list(net.children())[:-2])


BACKBONES = MappingProxyType({"small": lambda weights: small_backbone(), "resnet18": resnet18_backbone})
"""Backbone name -> builder from torchvision weights (only the ResNet takes any)."""
IMAGE_BACKBONES = tuple(BACKBONES)


class ImageEncoder(nn.Module):
    """Images (B, 3, H, W) in [0, 1] -> features (B, out_dim). Training takes a random crop of
    `crop_ratio` of each side (the same augmentation as LeRobot's diffusion policy), evaluation the centre."""

    def __init__(
        self,
        image_shape: tuple[int, int, int],
        out_dim: int = 64,
        backbone: str = "small",
        weights: str | None = None,
        keypoints: int = 32,
        crop_ratio: float = 0.9,
    ):
        super().__init__()
        _, height, width = image_shape
        self.crop = (max(8, round(height * crop_ratio)), max(8, round(width * crop_ratio)))
        self.backbone = BACKBONES[backbone](weights)  # the config checked the name
        with torch.no_grad():
            channels, fh, fw = self.backbone(torch.zeros(1, 3, *self.crop)).shape[1:]
        if fh * fw < 4:
            raise ValueError(
                f"images of {height}x{width} leave the {backbone} backbone a {fh}x{fw} feature map, where "
                "keypoints cannot move: give the cameras at least 32x32 pixels"
            )
        self.keypoints = SpatialSoftmax(channels, fh, fw, keypoints)
        self.projection = nn.Sequential(nn.Linear(2 * keypoints, out_dim), nn.ReLU())
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def forward(self, images: Tensor) -> Tensor:
        images = (self._crop(images) - self.mean) / self.std
        return self.projection(self.keypoints(self.backbone(images)).flatten(1))

    def _crop(self, images: Tensor) -> Tensor:
        (h, w), (ch, cw) = images.shape[-2:], self.crop
        if self.training:
            top = int(torch.randint(0, h - ch + 1, ()))
            left = int(torch.randint(0, w - cw + 1, ()))
        else:
            top, left = (h - ch) // 2, (w - cw) // 2
        return images[..., top : top + ch, left : left + cw]
