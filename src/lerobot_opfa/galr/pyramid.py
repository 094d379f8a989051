"""The three-level point pyramid of a hand (dense -> level 1 -> superpoints), fixed per hand.

Every point of a hand cloud is fixed to a rigid link, so a subsample chosen once in the links' own
frames stays well spread in every pose. Each link gets its share of each level (at least one point, so
fingertips always reach the superpoints) by farthest-point sampling within the link.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from lerobot_opfa.galr.neighbors import nearest_within
from lerobot_opfa.hands.geometry import allocate_points
from lerobot_opfa.hands.model import HandModel


@dataclass(frozen=True)
class PyramidIndex:
    """Indices into the dense cloud of one hand: level 1 (N1,), superpoints (N2,), a subset of level 1, and
    each level-1 point's neighbours on its own link (N1, K), shadow index N (see `link_neighbors`)."""

    level1: torch.Tensor
    superpoints: torch.Tensor
    stem: torch.Tensor

    def to(self, device) -> PyramidIndex:
        return PyramidIndex(self.level1.to(device), self.superpoints.to(device), self.stem.to(device))


def farthest_point_sampling(points: np.ndarray, k: int) -> np.ndarray:
    """Indices of `k` of the (M, 3) `points`, each the farthest from those chosen before (from index 0)."""
    chosen = np.zeros(k, dtype=np.int64)
    distance = np.linalg.norm(points - points[0], axis=1)
    for i in range(1, k):
        chosen[i] = int(distance.argmax())
        distance = np.minimum(distance, np.linalg.norm(points - points[chosen[i]], axis=1))
    return chosen


def _per_link_subset(local: np.ndarray, link_index: np.ndarray, candidates: np.ndarray, k: int) -> np.ndarray:
    """`k` of the `candidates` (indices into the dense cloud), shared out over links by their counts."""
    links = np.unique(link_index[candidates])
    per_link = [candidates[link_index[candidates] == link] for link in links]
    counts = allocate_points(np.array([len(p) for p in per_link], dtype=float), k, min_per_link=1)
    counts = np.minimum(counts, [len(p) for p in per_link])
    chosen = [p[farthest_point_sampling(local[p], c)] for p, c in zip(per_link, counts, strict=True) if c > 0]
    subset = np.concatenate(chosen)
    if len(subset) < k:  # a link had fewer candidates than its share: top up from the rest, spread out
        rest = np.setdiff1d(candidates, subset)
        subset = np.concatenate([subset, rest[np.linspace(0, len(rest) - 1, k - len(subset)).astype(int)]])
    return np.sort(subset)


def link_neighbors(
    local: torch.Tensor, link_index: torch.Tensor, queries: torch.Tensor, radius: float, limit: int
) -> torch.Tensor:
    """(Q, limit) indices of the dense points within `radius` of each query on the query's own link,
    nearest first, padded with the shadow index N. A link is rigid, so these are the same in every pose
    and are found once per hand, in the links' own frames: the stem's neighbourhoods need no search."""
    distances = torch.cdist(local[queries], local)
    distances[link_index[queries].unsqueeze(1) != link_index.unsqueeze(0)] = torch.inf
    return nearest_within(distances, radius, limit)


def pyramid_index(
    hand: HandModel,
    n_points: int,
    n_level1: int,
    n_superpoints: int,
    seed: int,
    stem_radius: float,
    stem_limit: int,
) -> PyramidIndex:
    if not n_points >= n_level1 >= n_superpoints >= len(hand.link_names):
        raise ValueError(
            f"need n_points >= n_level1 >= n_superpoints >= links of '{hand.name}' ({len(hand.link_names)}), "
            f"got {n_points}, {n_level1}, {n_superpoints}"
        )
    samples = hand.surface_samples(n_points, seed)
    local, link_index = samples.local_points.cpu().numpy(), samples.link_index.cpu().numpy()
    level1 = _per_link_subset(local, link_index, np.arange(n_points), n_level1)
    superpoints = _per_link_subset(local, link_index, level1, n_superpoints)
    level1 = torch.from_numpy(level1)
    stem = link_neighbors(
        samples.local_points.cpu(), samples.link_index.cpu(), level1, stem_radius, stem_limit
    )
    return PyramidIndex(level1, torch.from_numpy(superpoints), stem)
