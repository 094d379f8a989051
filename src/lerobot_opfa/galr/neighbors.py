"""Radius neighbourhoods in pure torch: k nearest supports of each query, those beyond the radius
replaced by a "shadow" index (one past the last support) whose feature is zero, as in KPConv."""

from __future__ import annotations

import torch


def radius_neighbors(
    queries: torch.Tensor, supports: torch.Tensor, radius: float, limit: int
) -> torch.Tensor:
    """(B, Q, 3), (B, S, 3) -> (B, Q, limit) support indices sorted by distance; shadow index = S."""
    return nearest_within(torch.cdist(queries, supports), radius, limit)


def nearest_within(distances: torch.Tensor, radius: float, limit: int) -> torch.Tensor:
    """(..., Q, S) distances -> (..., Q, limit) indices of each query's nearest supports, sorted; those
    beyond `radius`, and the padding when S < limit, are the shadow index S."""
    s = distances.shape[-1]
    k = min(limit, s)
    nearest, index = distances.topk(k, dim=-1, largest=False)
    index = index.masked_fill(nearest > radius, s)
    if k < limit:
        index = torch.cat([index, index.new_full((*index.shape[:-1], limit - k), s)], dim=-1)
    return index


def _shadowed_rows(
    values: torch.Tensor, index: torch.Tensor, shadow: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """`values` (B, S, C) with a `shadow` row after each cloud's, flattened to (B (S + 1), C), and the
    (B, Q, K) `index` as rows of that table: both gathers below read it with `index_select`, on the CPU
    about 1.5x faster than `gather` along dim 1."""
    b, s, c = values.shape
    table = torch.cat([values, values.new_full((b, 1, c), shadow)], dim=1).reshape(b * (s + 1), c)
    return table, index + torch.arange(b, device=index.device).view(b, 1, 1) * (s + 1)


def gather_neighbors(values: torch.Tensor, index: torch.Tensor, shadow: float = 0.0) -> torch.Tensor:
    """(B, S, C) values and (B, Q, K) indices -> (B, Q, K, C); the shadow index reads `shadow`."""
    table, rows = _shadowed_rows(values, index, shadow)
    return table.index_select(0, rows.reshape(-1)).view(*index.shape, values.shape[2])


def max_pool_neighbors(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """(B, S, C) values and (B, Q, K) indices -> (B, Q, C), each channel's largest value over the query's
    neighbours (the shadow index never wins). A running maximum over the K neighbours keeps one (B, Q, C)
    tensor in cache instead of writing and reading the (B, Q, K, C) gather: about 7x faster on the CPU."""
    table, rows = _shadowed_rows(values, index, -1e6)
    rows = rows.flatten(0, 1)
    pooled = table.index_select(0, rows[:, 0])
    for k in range(1, index.shape[2]):
        pooled = torch.maximum(pooled, table.index_select(0, rows[:, k]))
    return pooled.view(*index.shape[:2], values.shape[2])
