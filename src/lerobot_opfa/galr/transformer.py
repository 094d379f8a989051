"""Geometric transformer over superpoints (GeoTransformer, Qin et al., CVPR 2022), with the OPFA
semantic embedding added to GeoTransformer's structure embedding.

r^p_ij: sinusoidal embedding of the distance |p_i - p_j| / sigma_d, plus a pooled sinusoidal embedding of
the angles between (p_x - p_i) and (p_j - p_i) / sigma_a over the k nearest neighbours x of p_i.
r^s_j: the (finger u, segment v) label of superpoint j, either the paper's literal [u, v] W_S
("linear"), one learned vector per finger plus one per segment ("table"), or nothing ("none").
Attention uses r^p_ij as GeoTransformer's relative position term: score_ij = q_i . (k_j + W_r r_ij) /
sqrt(d_head). r^s goes either into the feature space, added to each superpoint's features (`features`,
the paper's r^s in R^{d_t}), or into the relative term, r_ij = r^p_ij + r^s_j (`attention`). Only
`features` lets a superpoint's value say which finger it is on: with `attention`, a bent index and a bent
middle fingertip give much the same values, and the pooled z barely tells them apart.
Angles use the cosine of the two directions (no cross products), and r lives in a narrow dimension
(`relative_dim`), the only change of substance for CPU speed.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
from torch import nn

from lerobot_opfa.hands.universal import FINGERS

SemanticEmbedding = Literal["linear", "table", "none"]
SemanticTarget = Literal["features", "attention"]
MAX_SEGMENTS = 8


def sinusoidal(x: torch.Tensor, dim: int, mean_over: int | None = None) -> torch.Tensor:
    """(...,) -> (..., dim) transformer-style sinusoidal embedding of a scalar; with `mean_over`, its mean
    over that dimension of x, taken before sine and cosine are interleaved (the widest tensor is the
    (..., dim / 2) angle table)."""
    freq = torch.exp(torch.arange(0, dim, 2, device=x.device, dtype=x.dtype) * (-math.log(10000.0) / dim))
    angles = x.unsqueeze(-1) * freq
    sin, cos = angles.sin(), angles.cos()
    if mean_over is not None:
        sin, cos = sin.mean(mean_over), cos.mean(mean_over)
    return torch.stack([sin, cos], dim=-1).flatten(-2)


class GeometricStructureEmbedding(nn.Module):
    """r^p_ij in a small dimension: the N x N (x k) tensors dominate the cost, so they stay narrow and the
    attention projects queries into this space instead of projecting r into the feature space."""

    def __init__(self, dim: int, sigma_d: float, sigma_a_degrees: float = 15.0, angle_k: int = 3):
        super().__init__()
        self.dim, self.sigma_d, self.angle_k = dim, sigma_d, angle_k
        self.factor_a = 180.0 / (sigma_a_degrees * math.pi)
        self.distance_proj = nn.Linear(dim, dim)
        self.angle_proj = nn.Linear(dim, dim)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """(B, N, 3) -> (B, N, N, dim)."""
        distance_code, angle_code = self.codes(points)
        embedding = self.distance_proj(distance_code)
        if angle_code is not None:
            embedding = embedding + self.angle_proj(angle_code)
        return embedding

    @torch.no_grad()
    def codes(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The sinusoidal codes of distances and angles, (B, N, N, dim) each: geometry only, no gradient."""
        offsets = points.unsqueeze(1) - points.unsqueeze(2)  # [b, i, j] = p_j - p_i
        distances = offsets.norm(dim=-1)
        distance_code = sinusoidal(distances / self.sigma_d, self.dim)
        k = min(self.angle_k, points.shape[1] - 1)
        if k == 0:
            return distance_code, None
        knn = distances.topk(k + 1, dim=-1, largest=False).indices[..., 1:]  # (B, N, k), self excluded
        directions = offsets / distances.unsqueeze(-1).clamp(min=1e-9)
        anchors = directions.gather(2, knn.unsqueeze(-1).expand(-1, -1, -1, 3))  # (B, N, k, 3)
        cosine = torch.einsum("bijc,bikc->bijk", directions, anchors).clamp(-1 + 1e-6, 1 - 1e-6)
        angles = torch.acos(cosine)  # (B, N, N, k): angle at p_i between p_j and p_i's k-th neighbour
        # Mean over the k neighbours (GeoTransformer takes the max): the projection then commutes with
        # the pooling, so the k-fold tensor is geometry only and needs no gradient.
        return distance_code, sinusoidal(angles * self.factor_a, self.dim, mean_over=3)


class SemanticLabelEmbedding(nn.Module):
    def __init__(self, dim: int, mode: SemanticEmbedding):
        super().__init__()
        self.mode = mode
        if mode == "linear":
            self.projection = nn.Linear(2, dim, bias=False)
        elif mode == "table":
            self.finger = nn.Embedding(len(FINGERS), dim)
            self.segment = nn.Embedding(MAX_SEGMENTS, dim)
        elif mode != "none":
            raise ValueError(f"semantic_embedding must be 'linear', 'table' or 'none', got '{mode}'")

    def forward(self, labels: torch.Tensor) -> torch.Tensor | None:
        """(B, N, 2) integer labels -> (B, N, dim), or None when switched off."""
        if self.mode == "linear":
            return self.projection(labels.float())
        if self.mode == "table":
            return self.finger(labels[..., 0]) + self.segment(labels[..., 1].clamp(max=MAX_SEGMENTS - 1))
        return None


class RelativeSelfAttentionLayer(nn.Module):
    """Post-norm transformer layer whose attention scores add q_i . W_r r_ij (GeoTransformer's RPE),
    computed as (W_r^T q_i) . r_ij so the N x N term stays in the narrow structure dimension."""

    def __init__(self, dim: int, heads: int, relative_dim: int, dropout: float = 0.0):
        super().__init__()
        self.heads, self.head_dim = heads, dim // heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.relative = nn.Parameter(
            torch.randn(heads, self.head_dim, relative_dim) / math.sqrt(relative_dim)
        )
        self.out = nn.Linear(dim, dim)
        self.norm1, self.norm2 = nn.LayerNorm(dim), nn.LayerNorm(dim)
        self.ffn = nn.Sequential(
            nn.Linear(dim, 2 * dim), nn.ReLU(), nn.Dropout(dropout), nn.Linear(2 * dim, dim)
        )

    def forward(self, x: torch.Tensor, relative: torch.Tensor) -> torch.Tensor:
        """x (B, N, D), relative (B, N, N, R) -> (B, N, D)."""
        b, n, _ = x.shape
        q, k, v = self.qkv(x).view(b, n, 3, self.heads, self.head_dim).unbind(2)  # each (B, N, H, d)
        q_relative = torch.einsum("bihd,hdr->bhir", q, self.relative)
        scores = torch.einsum("bihd,bjhd->bhij", q, k) + torch.einsum("bhir,bijr->bhij", q_relative, relative)
        attention = (scores / math.sqrt(self.head_dim)).softmax(dim=-1)
        context = torch.einsum("bhij,bjhd->bihd", attention, v).reshape(b, n, -1)
        x = self.norm1(x + self.out(context))
        return self.norm2(x + self.ffn(x))


class GeometricTransformer(nn.Module):
    def __init__(
        self,
        dim: int,
        heads: int,
        layers: int,
        sigma_d: float,
        semantic: SemanticEmbedding,
        relative_dim: int = 32,
        semantic_target: SemanticTarget = "features",
    ):
        super().__init__()
        self.semantic_target = semantic_target
        self.structure = GeometricStructureEmbedding(relative_dim, sigma_d)
        self.semantic = SemanticLabelEmbedding(
            dim if semantic_target == "features" else relative_dim, semantic
        )
        self.layers = nn.ModuleList(
            RelativeSelfAttentionLayer(dim, heads, relative_dim) for _ in range(layers)
        )

    def forward(self, features: torch.Tensor, points: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
        """features (B, N, D), points (B, N, 3), labels (B, N, 2) -> (B, N, D)."""
        relative = self.structure(points)
        semantic = self.semantic(labels)
        if semantic is not None:
            if self.semantic_target == "features":
                features = features + semantic
            else:
                relative = relative + semantic.unsqueeze(1)  # r_ij = r^p_ij + r^s_j
        for layer in self.layers:
            features = layer(features, relative)
        return features
