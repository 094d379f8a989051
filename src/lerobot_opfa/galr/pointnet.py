"""DP3's lean point encoder (Ze et al., RSS 2024): a per-point MLP with LayerNorm, max-pool, projection.
Used as the PointNet ablation of GaLR and as the policy's scene encoder."""

from __future__ import annotations

import torch
from torch import nn


class PointNetEncoder(nn.Module):
    def __init__(self, out_dim: int = 64, widths: tuple[int, ...] = (64, 128, 256), in_dim: int = 3):
        super().__init__()
        layers: list[nn.Module] = []
        for width in widths:
            layers += [nn.Linear(in_dim, width), nn.LayerNorm(width), nn.ReLU()]
            in_dim = width
        self.mlp = nn.Sequential(*layers)
        self.projection = nn.Sequential(nn.Linear(in_dim, out_dim), nn.LayerNorm(out_dim))

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """(B, N, C) -> (B, out_dim)."""
        return self.projection(self.mlp(points).max(dim=1).values)
