"""The GaLR latents of a training dataset's hand states, encoded once: a single-hand `galr` policy would
otherwise encode the whole state and action window of every sample at every step (a cloud and a KPConv
pass per frame), which is most of a step on a CPU. The encoder is frozen, so a state's z never changes;
rows are looked up by their exact float32 bytes, and a row not in the cache (a live robot's) is encoded."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from tqdm import tqdm

CHUNK = 1024


def _keys(q: torch.Tensor) -> list[bytes]:
    rows = np.ascontiguousarray(q.detach().to("cpu", torch.float32).numpy())
    return [row.tobytes() for row in rows]


class LatentCache:
    """z by joint vector, for one hand."""

    def __init__(self, q: torch.Tensor, encode: Callable[[torch.Tensor], torch.Tensor]):
        """`q` (N, dof): the rows to cache (duplicates are encoded once); `encode` (n, dof) -> (n, latent)."""
        unique = torch.from_numpy(np.unique(q.detach().to("cpu", torch.float32).numpy(), axis=0))
        chunks = unique.to(q.device).split(CHUNK)
        progress = tqdm(chunks, desc="encoding the hand states once", unit="chunk", disable=len(chunks) < 2)
        self._z = torch.cat([encode(c).detach().to("cpu", torch.float32) for c in progress])
        self._rows = {key: i for i, key in enumerate(_keys(unique))}

    def __len__(self) -> int:
        return len(self._rows)

    def encode(self, q: torch.Tensor, encode: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor:
        """(..., dof) -> (..., latent): cached rows gathered, the others encoded."""
        flat = q.reshape(-1, q.shape[-1])
        rows = torch.tensor([self._rows.get(key, -1) for key in _keys(flat)], dtype=torch.long)
        z = self._z[rows.clamp(min=0)].to(q.device)
        missing = (rows < 0).to(q.device)
        if missing.any():
            z[missing] = encode(flat[missing]).to(z.dtype)
        return z.reshape(*q.shape[:-1], -1)
