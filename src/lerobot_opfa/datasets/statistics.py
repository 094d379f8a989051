"""Per-embodiment statistics of a dataset's state and action columns, and the noise they are floored at.

`dataset merge` writes them into the merged dataset (`STATS_FILE`), with the noise floor of the cached
latents, so a policy's per-embodiment normalisation is fitted from the metadata instead of every frame.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from lerobot_opfa.hands.universal import UNIVERSAL_INDEX, UNIVERSAL_JOINTS

STATS_FILE = "meta/opfa_stats.safetensors"
"""Per key (`observation.state`, `action`): `{key}.count` (E,), `{key}.min|max|mean|std` (E, D) per
embodiment and `{key}.all_min|all_max|all_mean|all_std` (D,) over all frames; with cached latents
`latent_noise_floor` (d,)."""
REDUCTIONS: dict[str, tuple[Callable[[torch.Tensor], torch.Tensor], float]] = {
    "min": (lambda r: r.min(0).values, -torch.inf),
    "max": (lambda r: r.max(0).values, torch.inf),
    "mean": (lambda r: r.mean(0), 0.0),
    "std": (lambda r: r.std(0, unbiased=False), 1.0),
}
"""Each statistic and its value for an embodiment without frames."""

WRIST_NOISE = 0.01
"""Noise of a wrist entry in SI units: 1 cm of position, 0.57 deg of rotation."""
REVOLUTE_NOISE = 0.01
"""Noise of a revolute hand joint (rad): 0.57 deg."""
PRISMATIC_NOISE = 0.001
"""Noise of a prismatic hand joint (m): 1 mm of a gripper jaw's few centimetres."""
NOISE_SAMPLES = 512
"""Frames a noise floor is estimated on."""


def raw_noise(wrist_dim: int, universal_names: list[str]) -> torch.Tensor:
    """Physical noise of each raw state column: the wrist entries, then joints by kind."""
    kinds = [UNIVERSAL_JOINTS[UNIVERSAL_INDEX[u]].kind for u in universal_names]
    noise = [PRISMATIC_NOISE if kind == "prismatic" else REVOLUTE_NOISE for kind in kinds]
    return torch.tensor([WRIST_NOISE] * wrist_dim + noise)


def per_embodiment(
    values: torch.Tensor,
    ids: torch.Tensor,
    n_embodiments: int,
    pooled: torch.Tensor,
    reduce: Callable[[torch.Tensor], torch.Tensor],
    empty: float,
) -> torch.Tensor:
    """(E, D) table of `reduce` over each embodiment's rows; `pooled` entries over all rows; `empty`
    for an embodiment without rows."""
    stats = column_statistics(values, ids, n_embodiments, {"value": (reduce, empty)})
    return pool(stats, "value", pooled)


def column_statistics(
    values: torch.Tensor, ids: torch.Tensor, n_embodiments: int, reductions: dict = REDUCTIONS
) -> dict[str, torch.Tensor]:
    """`count` (E,), then per statistic `name` (E, D) per embodiment and `all_name` (D,) over all rows.
    `ids`: each row's embodiment (N,), or each entry's (N, D) (a two-handed robot's slots,
    `features.column_embodiments`), counted by the first entry's."""
    columns = ids if ids.dim() == 2 else ids[:, None].expand(-1, values.shape[-1])
    groups = {(): list(range(values.shape[-1]))} if ids.dim() == 1 else {}
    for entry, column in enumerate(columns.T if ids.dim() == 2 else []):  # one reduction per set of rows
        groups.setdefault(tuple(column.tolist()), []).append(entry)
    out = {"count": torch.bincount(columns[:, 0], minlength=n_embodiments)}
    for name, (reduce, empty) in reductions.items():
        table = torch.full((n_embodiments, values.shape[-1]), empty, dtype=values.dtype)
        for entries in groups.values():
            column = columns[:, entries[0]]
            for e in range(n_embodiments):
                rows = values[column == e][:, entries]
                if len(rows):
                    table[e, entries] = reduce(rows)
        out[name], out[f"all_{name}"] = table, reduce(values)
    return out


def pool(stats: dict[str, torch.Tensor], name: str, pooled: torch.Tensor) -> torch.Tensor:
    """The (E, D) table of statistic `name`, its `pooled` (D,) entries over all rows."""
    table = stats[name].clone()
    table[:, pooled] = stats[f"all_{name}"][pooled]
    return table


def noise_floor(
    encode: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    rows: torch.Tensor,
    encoded: torch.Tensor,
    ids: torch.Tensor,
    noise: torch.Tensor,
    n_embodiments: int,
    pooled: torch.Tensor,
) -> torch.Tensor:
    """(E, D): root-mean-square change of each encoded entry when every raw entry of `rows` (F, R) moves
    by its physical noise `noise` (R,) with a random sign. `encode(rows, kept)` maps raw rows (those of
    indices `kept`) to the encoded space (so the floor of z is what joint noise does to the GaLR latent);
    `encoded` (F, D) is `rows` already mapped, so only the noisy rows are encoded. `ids`: as
    `column_statistics` takes them."""
    generator = torch.Generator().manual_seed(0)
    keep = torch.randperm(len(rows), generator=generator)[:NOISE_SAMPLES]
    rows, ids = rows[keep], ids[keep]
    signs = torch.randint(0, 2, rows.shape, generator=generator).to(rows) * 2 - 1
    delta = encode(rows + signs * noise, keep) - encoded[keep]
    return per_embodiment(delta, ids, n_embodiments, pooled, lambda d: d.pow(2).mean(0).sqrt(), 0.0)


def statistics_of(stats: dict[str, torch.Tensor], key: str) -> dict[str, torch.Tensor]:
    """The statistics of one key (`observation.state`, `action`) of a dataset's `STATS_FILE`."""
    return {name[len(key) + 1 :]: value for name, value in stats.items() if name.startswith(f"{key}.")}


def write_statistics(root: Path, stats: dict[str, torch.Tensor]) -> None:
    save_file({k: v.contiguous() for k, v in stats.items()}, Path(root) / STATS_FILE)


def read_statistics(root: Path | str | None) -> dict[str, torch.Tensor] | None:
    """The dataset's statistics, or None when it has none (not merged, or merged before they existed)."""
    path = Path(root) / STATS_FILE if root is not None else None
    return load_file(path) if path is not None and path.is_file() else None
