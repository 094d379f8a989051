"""An episode recorded at one rate, read at another (`dataset merge` of inputs whose fps differ): by
timestamp, joint entries and absolute targets interpolated linearly between the frames either side, every
other feature (clouds, object state, cameras) taken from the nearest frame. A target time that falls on a
recorded frame takes that frame exactly. Timestamps that go backwards, or leave a gap longer than two
frames, are refused with the episode: interpolating across a gap would invent the motion in it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SNAP = 1e-5
"""s: a target time this close to a recorded frame's timestamp is that frame (timestamps are float32)."""
MAX_GAP = 2.0
"""Frames: the longest interval between consecutive timestamps read as a recording, not a gap."""


@dataclass(frozen=True)
class Resampling:
    """Per target frame: the recorded frames before and after it and how far it lies between them."""

    before: np.ndarray
    after: np.ndarray
    weight: np.ndarray
    """0 at `before`, 1 at `after`."""

    def interpolate(self, values: np.ndarray) -> np.ndarray:
        """(frames, ...) recorded values -> (targets, ...), linear in time."""
        weight = self.weight.reshape(-1, *[1] * (values.ndim - 1))
        return (1 - weight) * values[self.before] + weight * values[self.after]

    @property
    def nearest(self) -> np.ndarray:
        """Per target frame, the recorded frame nearest to it in time."""
        return np.where(self.weight < 0.5, self.before, self.after)


def resampling(timestamps: np.ndarray, fps: float, target_fps: float, where: str) -> Resampling:
    """The target frames at `target_fps` of an episode recorded at `fps` with `timestamps` (s, in frame
    order), from its first frame to its last; `where` names the episode in an error."""
    times = np.asarray(timestamps, dtype=np.float64)
    steps = np.diff(times)
    if (steps <= 0).any():
        frame = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise ValueError(f"{where}: timestamps go backwards at frame {frame} ({times[frame - 1]:.4f} s, then "
                         f"{times[frame]:.4f} s); fix the recording's timestamps to resample it")  # fmt: skip
    if (steps > MAX_GAP / fps + SNAP).any():
        frame = int(np.flatnonzero(steps > MAX_GAP / fps + SNAP)[0]) + 1
        raise ValueError(
            f"{where}: a gap of {steps[frame - 1]:.3f} s before frame {frame} ({steps[frame - 1] * fps:.1f} "
            f"frames at {fps:g} fps); split the episode there, or drop it, to resample it"
        )
    count = int(np.floor((times[-1] - times[0]) * target_fps + SNAP)) + 1
    targets = times[0] + np.arange(count) / target_fps
    after = np.clip(np.searchsorted(times, targets - SNAP), 0, len(times) - 1)
    before = np.maximum(after - 1, 0)
    span = times[after] - times[before]
    weight = np.where(span > 0, (targets - times[before]) / np.where(span > 0, span, 1.0), 1.0)
    weight = np.where(np.abs(targets - times[after]) <= SNAP, 1.0, np.clip(weight, 0.0, 1.0))
    return Resampling(before, after, weight)
