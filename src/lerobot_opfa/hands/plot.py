"""Pictures of hand point clouds, coloured by finger, from two viewpoints."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from lerobot_opfa.hands.universal import FINGERS

FINGER_COLOURS = ("#7f7f7f", "#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd")
VIEWS = (("front (palm side)", 0, 90), ("side (thumb side)", 0, 180))


def plot_clouds(clouds: dict[str, tuple[np.ndarray, np.ndarray]], out: str | Path, title: str = "") -> Path:
    """One row per named cloud ((N, 3) points, (N, 2) labels), one column per viewpoint; saves a PNG."""
    fig = Figure(figsize=(4.2 * len(VIEWS), 4.2 * len(clouds)))
    every = np.concatenate([points for points, _ in clouds.values()])
    centre, half = (every.max(0) + every.min(0)) / 2, (every.max(0) - every.min(0)).max() / 2 + 1e-3
    for row, (name, (points, labels)) in enumerate(clouds.items()):
        for col, (view, elev, azim) in enumerate(VIEWS):
            ax = fig.add_subplot(len(clouds), len(VIEWS), row * len(VIEWS) + col + 1, projection="3d")
            for u in np.unique(labels[:, 0]):
                sel = labels[:, 0] == u
                ax.scatter(*points[sel].T, s=2, c=FINGER_COLOURS[u], label=FINGERS[u], depthshade=False)
            ax.view_init(elev=elev, azim=azim)
            ax.set(xlim=(centre[0] - half, centre[0] + half), ylim=(centre[1] - half, centre[1] + half))
            ax.set(zlim=(centre[2] - half, centre[2] + half), xlabel="x", ylabel="y", zlabel="z")
            ax.set_box_aspect((1, 1, 1))
            ax.set_title(f"{name}: {view}", fontsize=9)
            if row == 0 and col == 0:
                ax.legend(loc="upper left", fontsize=7, markerscale=4)
    fig.suptitle(title)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return out
