"""Reading a LeRobotDataset's columns in bulk, and writing a new dataset so that it appears whole or not
at all (an interrupted merge leaves nothing behind under the output path)."""

from __future__ import annotations

import contextlib
import errno
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


OPFA_META_FILE = "meta/opfa.json"
"""What lerobot-opfa records about a dataset: `hands` (user hands' specs: name -> {spec, sha256}); for a
merged dataset also its inputs and, with cached latents, the GaLR that computed them (`galr`, as given to
the merge, and `galr_fingerprint`); for `dataset clouds` output the depth `cameras`."""
OPFA_INFO_KEY = "opfa"
"""`meta/info.json` keeps a copy of that record in `features["observation.state"]["info"]["opfa"]`: LeRobot's
own tools (`lerobot-edit-dataset`) rewrite `meta/` keeping only the features' entries of info.json."""


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
    cleaned first (`clean_stale_siblings`). A full disk is a one-line error."""
    output = Path(output).resolve()
    clean_stale_siblings(output)
    if output.exists() and not overwrite:
        raise FileExistsError(f"{output} exists; pass --overwrite (overwrite=True) to replace it")
    output.parent.mkdir(parents=True, exist_ok=True)
    tag = f"{os.getpid()}-{uuid.uuid4().hex[:8]}"
    partial = output.parent / f".{output.name}{PARTIAL}{tag}"
    try:
        yield partial
        _publish(partial, output, overwrite, output.parent / f".{output.name}{OLD}{tag}")
    except OSError as err:
        if err.errno in (errno.ENOSPC, errno.EDQUOT) or os.strerror(errno.ENOSPC) in str(err):
            raise RuntimeError(
                f"{output} was not written: the disk is full ({os.strerror(errno.ENOSPC)}); nothing was left "
                "behind: free some space and run again"
            ) from None
        raise
    finally:
        if partial.exists():
            shutil.rmtree(partial, ignore_errors=True)


def _publish(partial: Path, output: Path, overwrite: bool, old: Path) -> None:
    """Renames `partial` to `output`. Without `overwrite` an `output` that appeared while it was written
    (another run given the same output) is kept, not replaced: renaming a folder onto a non-empty one
    fails, so two runs cannot both succeed."""
    if overwrite and output.exists():
        output.rename(old)
    try:
        if not overwrite and output.exists():
            raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST))
        partial.rename(output)
    except OSError as err:
        if err.errno not in (errno.EEXIST, errno.ENOTEMPTY, errno.ENOTDIR):
            raise
        raise FileExistsError(
            f"{output} appeared while this run was writing it (another run given the same output?); it is "
            "left as it is and this run's result is discarded: choose another output, or pass --overwrite"
        ) from None
    if old.exists():
        shutil.rmtree(old)


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
    `output` when the block succeeds, with a copy of the record the block wrote (`keep_record`). On failure
    the dataset's writers are closed before the folder is deleted (`_close_writers`)."""
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
            _close_writers(dataset)
            raise
        keep_record(partial)


def _close_writers(dataset: LeRobotDataset) -> None:
    """Closes a failed dataset's writers, dropping what they could not write. A write that failed (a full
    disk) fails again in `finalize`, which then never reaches the metadata: its buffered episodes would be
    flushed when LeRobot collects the dataset, recreating the folder deleted meanwhile. LeRobot offers no
    call that drops them, hence its private buffer."""
    try:
        dataset.finalize()
    except Exception:
        if dataset.writer is not None:
            with contextlib.suppress(Exception):
                dataset.writer.stop_image_writer()
        dataset.meta._metadata_buffer.clear()
        with contextlib.suppress(Exception):
            dataset.meta.finalize()


def keep_record(root: Path) -> None:
    """Copies the dataset's `OPFA_META_FILE` into its `meta/info.json` (`OPFA_INFO_KEY`), or removes a copy
    its features inherited from an input when it has no record."""
    from lerobot.utils.constants import OBS_STATE

    path = root / "meta" / "info.json"
    info = read_json(path)
    state = info["features"].get(OBS_STATE)
    if state is None:
        return
    extra = {k: v for k, v in (state.get("info") or {}).items() if k != OPFA_INFO_KEY}
    if (root / OPFA_META_FILE).is_file():
        extra[OPFA_INFO_KEY] = read_json(root / OPFA_META_FILE)
    if extra:
        state["info"] = extra
    else:
        state.pop("info", None)
    path.write_text(json.dumps(info, indent=4, ensure_ascii=False))


def embedded_record(root: Path | str) -> dict | None:
    """The copy of a dataset's record its `meta/info.json` keeps (`keep_record`), if any."""
    from lerobot.utils.constants import OBS_STATE  # imported here: light commands read this module

    path = Path(root) / "meta" / "info.json"
    if not path.is_file():
        return None
    state = read_json(path).get("features", {}).get(OBS_STATE) or {}
    return (state.get("info") or {}).get(OPFA_INFO_KEY)
