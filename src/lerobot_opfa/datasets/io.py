"""Reading a LeRobotDataset's columns in bulk, and writing a new dataset so that it appears whole or not
at all (an interrupted merge leaves nothing behind under the output path)."""

from __future__ import annotations

import contextlib
import glob
import json
import os
import shutil
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

if TYPE_CHECKING:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset


def read_json(path: Path | str) -> Any:
    """A JSON file's content; a file that does not parse is an error naming it."""
    try:
        return json.loads(Path(path).read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{path} is not valid JSON ({err}); restore it or record the data again") from None


def check_dataset_folder(root: Path | str) -> None:
    """A LeRobotDataset folder whose JSON metadata parse, checked before LeRobot reads it (its own error
    would not name the file)."""
    root = Path(root)
    if not (root / "meta" / "info.json").is_file():
        raise ValueError(f"{root}: not a LeRobotDataset folder (no meta/info.json)")
    for path in sorted((root / "meta").glob("*.json")):
        read_json(path)
    for part in ("meta/episodes", "data"):
        if not any((root / part).rglob("*.parquet")):
            raise ValueError(
                f"{root}: a LeRobotDataset folder without {part}/*.parquet; restore it or record again"
            )


def check_outside_inputs(inputs: list[Path | str], output: Path | str) -> list[Path]:
    """The inputs, resolved: none named twice (its episodes would be read twice), none the output or
    inside or around it (a writer replaces its output and would destroy that input)."""
    roots, output = [Path(p).resolve() for p in inputs], Path(output).resolve()
    twice = sorted({str(r) for r in roots if roots.count(r) > 1})
    if twice:
        raise ValueError(f"the inputs name {', '.join(twice)} more than once")
    for root in roots:
        if root == output or output.is_relative_to(root) or root.is_relative_to(output):
            raise ValueError(
                f"--output {output} would write over the input {root}; choose an output outside every input"
            )
    return roots


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
    on any error (an interrupt included) it is deleted. What a killed writer left beside `output` is
    cleaned first (`clean_stale_siblings`)."""
    output = Path(output).resolve()
    clean_stale_siblings(output)
    if output.exists() and not overwrite:
        raise FileExistsError(f"{output} exists; pass --overwrite (overwrite=True) to replace it")
    output.parent.mkdir(parents=True, exist_ok=True)
    tag = f"{os.getpid()}-{uuid.uuid4().hex[:8]}"
    partial = output.parent / f".{output.name}{PARTIAL}{tag}"
    try:
        yield partial
        if output.exists():
            old = output.parent / f".{output.name}{OLD}{tag}"
            output.rename(old)
            partial.rename(output)
            shutil.rmtree(old)
        else:
            partial.rename(output)
    finally:
        if partial.exists():
            shutil.rmtree(partial, ignore_errors=True)


PARTIAL, OLD = ".partial-", ".old-"
"""Infixes of the siblings `atomic_directory` writes (`.<name>.partial-<pid>-<hex>`, `.<name>.old-...`)."""


def clean_stale_siblings(output: Path) -> None:
    """Removes the partial folders beside `output` that no live process is writing (a killed writer's, or
    one of a version that tagged them without its pid), and puts back an `output` that a writer killed
    mid-replacement had moved aside."""
    if not output.parent.is_dir():
        return
    for infix in (PARTIAL, OLD):
        for sibling in output.parent.glob(f".{glob.escape(output.name)}{infix}*"):
            if _writer_alive(sibling.name.rsplit(infix, 1)[1]):
                continue
            if infix == OLD and not output.exists():
                sibling.rename(output)
            else:
                shutil.rmtree(sibling, ignore_errors=True)


def _writer_alive(tag: str) -> bool:
    pid, _, _ = tag.partition("-")
    if not pid.isdigit() or int(pid) == os.getpid():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def new_dataset(output: Path | str, overwrite: bool = False, **create: Any) -> Iterator[LeRobotDataset]:
    """A LeRobotDataset (`LeRobotDataset.create(**create)`) written under a partial folder that becomes
    `output` when the block succeeds. On failure the dataset's writers are closed before the folder is
    deleted: LeRobot's metadata flushes its episode buffer when it is collected, and would otherwise
    recreate the deleted folder afterwards."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    output = Path(output)
    if overwrite and output.exists() and not (output / "meta" / "info.json").is_file():
        raise FileExistsError(
            f"{output} exists and is not a LeRobotDataset; --overwrite replaces only a dataset: choose "
            "another output"
        )
    with atomic_directory(output, overwrite) as partial:
        dataset = LeRobotDataset.create(root=partial, **create)
        try:
            yield dataset
            dataset.finalize()
        except BaseException:
            with contextlib.suppress(Exception):
                dataset.finalize()
            raise
