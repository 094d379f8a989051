"""Radius neighbourhoods in pure torch: k nearest supports of each query, those beyond the radius
replaced by a "shadow" index (one past the last support) whose feature is zero, as in KPConv."""

from __future__ import annotations

import torch


def radius_neighbors(
    queries: torch.Tensor, supports: torch.Tensor, radius: float, limit: int
) -> torch.Tensor:
    """(B, Q, 3), (B, S, 3) -> (B, Q, limit) support indices sorted by distance; shadow index = S."""
    distances = torch.cdist(queries, supports)
    k = min(limit, supports.shape[1])
    nearest, index = distances.topk(k, dim=-1, largest=False)
    index = index.masked_fill(nearest > radius, supports.shape[1])
    if k < limit:
        index = torch.cat([index, index.new_full((*index.shape[:2], limit - k), supports.shape[1])], dim=-1)
    return index


def gather_neighbors(values: torch.Tensor, index: torch.Tensor, shadow: float = 0.0) -> torch.Tensor:
    """(B, S, C) values and (B, Q, K) indices -> (B, Q, K, C); the shadow index reads `shadow`."""
    padded = torch.cat([values, values.new_full((values.shape[0], 1, values.shape[2]), shadow)], dim=1)
    b, q, k = index.shape
    flat = padded.gather(1, index.reshape(b, q * k, 1).expand(-1, -1, values.shape[2]))
    return flat.reshape(b, q, k, values.shape[2])
