"""Spatial regions: a named 3 x 3 grid over the table, so demonstrations of each embodiment can be
collected in distinct parts of the workspace (the paper's nine-region split) and policies tested on the
others."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Table-top area the grid covers (metres, world frame; the robot stands at -x looking towards +x).
GRID_X = (-0.15, 0.15)
GRID_Y = (-0.18, 0.18)
ROWS = ("near", "mid", "far")  # along +x, away from the robot
COLS = ("right", "center", "left")  # along +y


@dataclass(frozen=True)
class Region:
    name: str
    x: tuple[float, float]
    y: tuple[float, float]

    def sample(self, rng: np.random.Generator, margin: float = 0.01) -> np.ndarray:
        """A uniform (x, y) inside the cell, `margin` away from its borders."""
        return np.array(
            [
                rng.uniform(self.x[0] + margin, self.x[1] - margin),
                rng.uniform(self.y[0] + margin, self.y[1] - margin),
            ]
        )


def _grid() -> dict[str, Region]:
    xs = np.linspace(*GRID_X, len(ROWS) + 1)
    ys = np.linspace(*GRID_Y, len(COLS) + 1)
    return {
        f"{row}_{col}": Region(
            f"{row}_{col}", (float(xs[i]), float(xs[i + 1])), (float(ys[j]), float(ys[j + 1]))
        )
        for i, row in enumerate(ROWS)
        for j, col in enumerate(COLS)
    }


REGIONS: dict[str, Region] = _grid()


def parse_regions(regions: str | list[str] | tuple[str, ...]) -> list[str]:
    """'all', one name, a comma-separated list or a list of names -> the validated region names."""
    names = regions.split(",") if isinstance(regions, str) else list(regions)
    names = [n.strip() for n in names if n.strip()]
    if names == ["all"] or not names:
        return list(REGIONS)
    unknown = [n for n in names if n not in REGIONS]
    if unknown:
        raise ValueError(f"unknown region(s) {unknown}; valid regions: all, {', '.join(REGIONS)}")
    return names
