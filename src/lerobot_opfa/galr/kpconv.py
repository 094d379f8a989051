"""Kernel point convolution (Thomas et al., ICCV 2019) with linear influence, and KPConv's residual
bottleneck block. Normalisation is per point (LayerNorm), so clouds in a batch never influence each
other."""

from __future__ import annotations

import math

import torch
from torch import nn

from lerobot_opfa.galr.neighbors import gather_neighbors, max_pool_neighbors

KERNEL_SHELL_RADIUS = 0.66


def kernel_points(n: int = 15) -> torch.Tensor:
    """(n, 3) kernel points in the unit ball: one at the centre, the rest spread evenly (Fibonacci
    lattice) on a shell at 0.66, KPConv's rigid disposition. Deterministic, no optimisation needed."""
    i = torch.arange(n - 1, dtype=torch.float64) + 0.5
    polar = torch.acos(1 - 2 * i / (n - 1))
    azimuth = math.pi * (1 + 5**0.5) * i
    shell = torch.stack([polar.sin() * azimuth.cos(), polar.sin() * azimuth.sin(), polar.cos()], dim=-1)
    return torch.cat([torch.zeros(1, 3, dtype=torch.float64), KERNEL_SHELL_RADIUS * shell]).float()


class KPConv(nn.Module):
    """g(x) = sum_i sum_k max(0, 1 - |y_i - x_k| / sigma) W_k f_i over the neighbours y_i of x."""

    def __init__(self, in_channels: int, out_channels: int, radius: float, sigma: float, n_kernel: int = 15):
        super().__init__()
        self.radius, self.sigma = radius, sigma
        self.register_buffer("kernel", kernel_points(n_kernel) * radius)
        self.weight = nn.Parameter(torch.empty(n_kernel, in_channels, out_channels))
        nn.init.kaiming_uniform_(self.weight.view(n_kernel * in_channels, out_channels).T, a=math.sqrt(5))

    def forward(self, queries, supports, features, neighbors) -> torch.Tensor:
        """queries (B, Q, 3), supports (B, S, 3), features (B, S, C_in) or None for a constant 1 (the stem,
        which sees geometry only), neighbors (B, Q, K) -> (B, Q, C_out)."""
        influence = self.influence(queries, supports, neighbors)  # (B, Q, K, n_kernel)
        if features is None:
            weighted = influence.sum(2)  # (B, Q, n_kernel)
        else:
            weighted = influence.transpose(2, 3) @ gather_neighbors(features, neighbors)  # (B, Q, n, C_in)
        out = weighted.flatten(2) @ self.weight.flatten(0, 1)
        # Average over the neighbours that exist (KPConv's density normalisation).
        count = (neighbors < supports.shape[1]).sum(-1, keepdim=True).clamp(min=1)
        return out / count

    @torch.no_grad()
    def influence(self, queries, supports, neighbors) -> torch.Tensor:
        """max(0, 1 - |y_i - x_k| / sigma) as (B, Q, K, n_kernel). Geometry only (the kernel is fixed and
        clouds carry no gradient), so it is built in place: one (B, Q, K, n_kernel) buffer, no copies."""
        relative = gather_neighbors(supports, neighbors, shadow=1e6) - queries.unsqueeze(2)  # (B, Q, K, 3)
        # |y - x_k|^2 = |y|^2 - 2 y.x_k + |x_k|^2, without a (B, Q, K, n_kernel, 3) tensor.
        squared = relative @ (-2 * self.kernel.T)
        squared.add_(relative.square().sum(-1, keepdim=True)).add_(self.kernel.square().sum(-1))
        return squared.clamp_(min=0).sqrt_().mul_(-1 / self.sigma).add_(1).clamp_(min=0)


class UnaryBlock(nn.Sequential):
    def __init__(self, in_channels: int, out_channels: int, activate: bool = True):
        layers = [nn.Linear(in_channels, out_channels), nn.LayerNorm(out_channels)]
        super().__init__(*layers, *([nn.LeakyReLU(0.1)] if activate else []))


class ResidualBlock(nn.Module):
    """KPConv bottleneck: unary down to C_out/4, KPConv, unary up, plus a shortcut that max-pools each
    query's neighbourhood when the block is strided (queries are a coarser level than supports)."""

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        radius: float,
        sigma: float,
        strided: bool,
        n_kernel: int = 15,
    ):
        super().__init__()
        self.strided = strided
        mid = out_channels // 4
        self.reduce = UnaryBlock(in_channels, mid)
        self.conv = KPConv(mid, mid, radius, sigma, n_kernel)
        self.conv_norm = nn.Sequential(nn.LayerNorm(mid), nn.LeakyReLU(0.1))
        self.expand = UnaryBlock(mid, out_channels, activate=False)
        self.shortcut = (
            UnaryBlock(in_channels, out_channels, activate=False) if in_channels != out_channels else None
        )
        self.activation = nn.LeakyReLU(0.1)

    def forward(self, queries, supports, features, neighbors) -> torch.Tensor:
        x = self.conv_norm(self.conv(queries, supports, self.reduce(features), neighbors))
        x = self.expand(x)
        if self.strided:
            shortcut = max_pool_neighbors(features, neighbors)
        else:
            shortcut = features
        if self.shortcut is not None:
            shortcut = self.shortcut(shortcut)
        return self.activation(x + shortcut)
