"""A frozen GaLR's function of a training dataset's rows, computed once per row: a single-hand `galr` policy
would otherwise encode the whole state and action window of every sample at every step (a cloud and a
KPConv pass per frame), which is most of a step on a CPU. The GaLR is frozen, so a row's result never
changes; rows are looked up by their exact float32 bytes. A live robot's rows are computed and not kept,
so a long deployment does not grow the cache."""

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
    """`function`'s result by row, for one hand: z by joint vector, or a latent's round trip by latent."""

    def __init__(self, function: Callable[[torch.Tensor], torch.Tensor], rows: torch.Tensor | None = None):
        """`function` (n, width) -> (n, latent); `rows` (N, width): computed now (duplicates once), with a
        progress bar; the cache otherwise fills as `__call__` is asked to keep rows."""
        self._function = function
        self._rows: dict[bytes, int] = {}
        self._values: torch.Tensor | None = None
        if rows is not None:
            self._compute(rows)

    def __len__(self) -> int:
        return len(self._rows)

    @staticmethod
    def _unique(rows: torch.Tensor) -> torch.Tensor:
        unique = np.unique(rows.detach().to("cpu", torch.float32).numpy(), axis=0)
        return torch.from_numpy(unique).to(rows.device)

    def _compute(self, rows: torch.Tensor) -> None:
        """Computes and keeps `rows` (duplicates once), with a progress bar where they are many."""
        chunks = self._unique(rows).split(CHUNK)
        for chunk in tqdm(
            chunks, desc="encoding the hand states once", unit="chunk", disable=len(chunks) < 2
        ):
            values = self._function(chunk).detach().to("cpu", torch.float32)
            start = len(self._rows)
            self._rows.update({key: start + i for i, key in enumerate(_keys(chunk))})
            self._values = values if self._values is None else torch.cat([self._values, values])

    def __call__(self, q: torch.Tensor, keep: bool = False) -> torch.Tensor:
        """(..., width) -> (..., latent): known rows gathered, the others computed (and kept if `keep`: a
        training dataset's rows, which are finite)."""
        flat = q.reshape(-1, q.shape[-1])
        rows = torch.tensor([self._rows.get(key, -1) for key in _keys(flat)], dtype=torch.long)
        missing = rows < 0
        if missing.any() and keep:
            self._compute(flat[missing.to(flat.device)])
            return self(q)
        out = None
        if self._values is not None:
            out = self._values[rows.clamp(min=0)].to(q.device)
        if missing.any():
            computed = self._function(flat[missing.to(flat.device)])
            if out is None:
                out = computed.new_zeros(len(flat), computed.shape[-1])
            out[missing.to(q.device)] = computed.to(out.dtype)
        return out.reshape(*q.shape[:-1], -1)
