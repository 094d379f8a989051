"""A LeRobotDataset held in memory, for training that is not bound by dataset reads.

`LeRobotDataset.__getitem__` reads every frame's delta-timestamp window row by row from Arrow (a horizon-16
action window is 16 row reads, converted through Python lists) and decodes every camera frame of the window
from video, so on a CPU a training step of a small policy spends most of its time there. `InMemoryDataset`
reads every column once into an array, decodes every video frame once (colour frames kept as uint8), and
serves an item, or a whole batch through `__getitems__` (which torch's DataLoader calls when present), by
index gathers. Items are `LeRobotDataset`'s: the same keys, dtypes and shapes, windows clamped to the
episode's bounds with the same `*_is_pad` flags, and the task string.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from lerobot.datasets.language import LANGUAGE_COLUMNS
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from tqdm import tqdm

_NON_NUMERIC = ("string",)
MAX_VIDEO_BYTES = 8 * 2**30
"""Decoded frames held at most; a larger dataset trains with lerobot-train, which decodes per sample."""


class InMemoryDataset(torch.utils.data.Dataset):
    """`source`'s frames in memory, served as `source` serves them. The attributes LeRobot's training loop
    and `EpisodeAwareSampler` read (`meta`, `episodes`, `num_frames`, `absolute_to_relative_idx`, ...) are
    `source`'s; anything else is looked up on `source` too, so code written for a LeRobotDataset keeps
    working."""

    def __init__(self, source: LeRobotDataset):
        features = source.meta.features
        unsupported = sorted(
            key
            for key, ft in features.items()
            if ft["dtype"] in _NON_NUMERIC
            or key in LANGUAGE_COLUMNS
            or (ft["dtype"] == "image" and key in source.meta.depth_keys)
        )
        if unsupported:
            raise ValueError(
                f"the in-memory fast path is for numeric, image and video features; {source.repo_id} has "
                f"others ({', '.join(unsupported)}): train it with lerobot-train"
            )
        if source.reader._image_transforms is not None:
            raise ValueError(
                "the in-memory fast path serves frames as recorded; train with image transforms "
                "(--dataset.image_transforms.enable=true) through lerobot-train"
            )
        self.source = source
        self.meta = source.meta
        self.episodes = source.episodes
        self.absolute_to_relative_idx = source.absolute_to_relative_idx
        images = [k for k, ft in features.items() if ft["dtype"] == "image"]
        self._columns = _read_columns(source.hf_dataset, source[0] if len(source) else {}, images)
        self._colour = {k for k in source.meta.video_keys if k not in source.meta.depth_keys} | set(images)
        self._columns |= _read_videos(source, self._columns, self._colour)
        self._tasks = list(source.meta.tasks.index)
        self._windows = self._build_windows(source.reader.delta_indices or {})

    def _build_windows(self, delta_indices: dict[str, list[int]]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Per windowed key: the row of every (frame, delta) and its padding flag, as `DatasetReader`
        computes them (query index clamped to the frame's episode, padded where it falls outside)."""
        absolute, episode = self._columns["index"], self._columns["episode_index"]
        bounds = self.meta.episodes.with_format("numpy")
        starts = np.asarray(bounds["dataset_from_index"][:], dtype=np.int64)[episode][:, None]
        ends = np.asarray(bounds["dataset_to_index"][:], dtype=np.int64)[episode][:, None]
        to_row = np.full(int(absolute.max()) + 1 if len(absolute) else 0, -1, dtype=np.int64)
        to_row[absolute] = np.arange(len(absolute))
        by_deltas: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}
        windows = {}
        for key, deltas in delta_indices.items():
            if key not in self._columns:
                raise ValueError(f"delta timestamps name '{key}', not a numeric column of the dataset")
            deltas = tuple(int(d) for d in deltas)
            if deltas not in by_deltas:
                query = absolute[:, None] + np.asarray(deltas, dtype=np.int64)[None, :]
                rows = to_row[np.clip(query, starts, ends - 1)]
                if (rows < 0).any():
                    raise ValueError(f"{self.source.repo_id}: episode frames are missing from its data files")
                by_deltas[deltas] = (rows, (query < starts) | (query >= ends))
            windows[key] = by_deltas[deltas]
        return windows

    # --- what LeRobot's training loop reads -----------------------------------------------------------
    @property
    def num_frames(self) -> int:
        return len(self._columns["index"])

    @property
    def num_episodes(self) -> int:
        return self.source.num_episodes

    @property
    def fps(self) -> int:
        return self.meta.fps

    @property
    def features(self) -> dict[str, dict]:
        return self.meta.features

    def __getattr__(self, name: str) -> Any:
        # Only called for attributes not found on the instance; `source` itself must not recurse (it is
        # missing while an unpickled copy is being rebuilt in a loader worker).
        if name == "source" or name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.source, name)

    def __len__(self) -> int:
        return self.num_frames

    def __repr__(self) -> str:
        return f"InMemoryDataset({self.source.repo_id!r}, {self.num_frames} frames)"

    # --- items ----------------------------------------------------------------------------------------
    def __getitem__(self, idx: int) -> dict:
        if isinstance(idx, slice):
            return self.__getitems__(list(range(*idx.indices(len(self)))))
        return self.__getitems__([idx])[0]

    def __getitems__(self, indices: list[int]) -> list[dict]:
        """A batch of items gathered at once (one NumPy gather per key, not per key and item: NumPy's runs
        on this thread, where torch's would start its thread pool for every key); the items are views into
        the gathered batch, which the DataLoader's collate stacks."""
        rows = np.asarray(indices, dtype=np.int64)
        n = len(self)
        if rows.size and (rows.min() < -n or rows.max() >= n):
            raise IndexError(f"index out of range for a dataset of {n} frames")
        rows = rows % max(n, 1)
        batch: dict[str, torch.Tensor] = {}
        for key, column in self._columns.items():
            window = self._windows.get(key)
            batch[key] = torch.from_numpy(column[rows if window is None else window[0][rows]])
            if key in self._colour:  # LeRobot serves colour frames as float32 in [0, 1]
                batch[key] = batch[key].to(torch.float32).div_(255)
        for key, (_, pad) in self._windows.items():
            batch[f"{key}_is_pad"] = torch.from_numpy(pad[rows])
        tasks = [self._tasks[i] for i in batch["task_index"].tolist()]
        split = {key: value.unbind(0) for key, value in batch.items()}
        return [
            {**{key: values[i] for key, values in split.items()}, "task": task}
            for i, task in enumerate(tasks)
        ]


def _read_columns(hf_dataset, reference: dict, images: list[str]) -> dict[str, np.ndarray]:
    """Every column of `hf_dataset` as one array, in the dtype and per-frame shape LeRobot's own
    conversion (`hf_transform_to_torch`, compared on `reference`, the first item) gives; `images` (8-bit
    pictures stored in the table) as uint8 (C, H, W), which that conversion gives divided by 255."""
    table = hf_dataset.with_format("numpy")
    columns = {}
    for key in images:
        pictures = torch.stack(list(hf_dataset[key]))
        columns[key] = torch.round(pictures * 255).to(torch.uint8).numpy()
    for key in [k for k in hf_dataset.column_names if k not in images]:
        values = table[key][:]
        if values.dtype == object:
            raise ValueError(f"the in-memory fast path needs fixed-shape numeric columns; '{key}' is not")
        column = torch.from_numpy(np.ascontiguousarray(values))
        if key in reference:
            expected = reference[key]
            if not isinstance(expected, torch.Tensor):
                raise ValueError(f"the in-memory fast path needs numeric columns; '{key}' is not")
            column = column.to(expected.dtype)
        columns[key] = column.numpy()
    return columns


def _read_videos(source: LeRobotDataset, columns: dict[str, np.ndarray], colour: set[str]) -> dict:
    """Every frame of every video feature, in row order, decoded once by LeRobot's own reader (depth maps
    dequantised as it serves them); colour frames as uint8 (they were recorded as such), depth as float32.
    The reader gives colour as float32 in [0, 1], or as uint8 where the dataset was opened with
    `return_uint8` (as `lerobot-train`'s dataset factory opens it)."""
    keys = list(source.meta.video_keys)
    if not keys:
        return {}
    n_frames = len(columns["index"])
    frame_bytes = sum(
        int(np.prod(source.meta.features[k]["shape"])) * (1 if k in colour else 4) for k in keys
    )
    if n_frames * frame_bytes > MAX_VIDEO_BYTES:
        raise ValueError(
            f"{source.repo_id}'s {n_frames} video frames take {n_frames * frame_bytes / 2**30:.1f} GiB "
            f"decoded (more than {MAX_VIDEO_BYTES / 2**30:.0f}): train it with lerobot-train"
        )
    videos: dict[str, np.ndarray] = {}
    episodes, timestamps = columns["episode_index"], columns["timestamp"]
    for episode in tqdm(np.unique(episodes), desc="decoding video", unit="episode", leave=False):
        rows = np.flatnonzero(episodes == episode)
        query = {k: timestamps[rows].astype(np.float64).tolist() for k in keys}
        frames = source.reader._query_videos(query, int(episode))  # LeRobot's decode and dequantise
        for key, value in frames.items():
            value = value.reshape(len(rows), *value.shape[-3:]).numpy()
            if key in colour and value.dtype != np.uint8:  # LeRobot's training decodes to uint8 already
                value = np.rint(value * 255).astype(np.uint8)
            if key not in videos:
                videos[key] = np.empty((n_frames, *value.shape[1:]), dtype=value.dtype)
            videos[key][rows] = value
    return videos
