"""Reading a LeRobotDataset's columns in bulk, and writing a new dataset so that it appears whole or not
at all (an interrupted merge leaves nothing behind under the output path)."""

from __future__ import annotations

import contextlib
import shutil
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq


def read_columns(root: Path | str, columns: list[str]) -> dict[str, np.ndarray]:
    """Whole columns of the dataset under `root` (all frames, in file order): vectors as (F, D) arrays."""
    files = sorted((Path(root) / "data").rglob("*.parquet"))
    if not files:
        raise FileNotFoundError(f"no parquet files under {Path(root) / 'data'}")
    table = pa.concat_tables([pq.read_table(f, columns=columns) for f in files])
    out = {}
    for name in columns:
        column = table.column(name).combine_chunks()
        if pa.types.is_fixed_size_list(column.type) or pa.types.is_list(column.type):
            out[name] = column.flatten().to_numpy(zero_copy_only=False).reshape(len(column), -1)
        else:
            out[name] = column.to_numpy(zero_copy_only=False)
    return out


@contextlib.contextmanager
def atomic_directory(output: Path | str, overwrite: bool = False) -> Iterator[Path]:
    """Yields a fresh sibling temp path to write into; on success it replaces `output` in one rename,
    on any error it is deleted."""
    output = Path(output).resolve()
    if output.exists() and not overwrite:
        raise FileExistsError(f"{output} exists; pass --overwrite (overwrite=True) to replace it")
    output.parent.mkdir(parents=True, exist_ok=True)
    tag = uuid.uuid4().hex[:8]
    partial = output.parent / f".{output.name}.partial-{tag}"
    try:
        yield partial
        if output.exists():
            old = output.parent / f".{output.name}.old-{tag}"
            output.rename(old)
            partial.rename(output)
            shutil.rmtree(old)
        else:
            partial.rename(output)
    finally:
        if partial.exists():
            shutil.rmtree(partial)
