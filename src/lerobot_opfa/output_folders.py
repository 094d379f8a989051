"""Output folders checked before any work: one that cannot be written would otherwise fail only at the end
(a training run's first checkpoint, a dataset's final rename), as an OSError traceback; and one a run uses
alone, held while it runs, so that a second run into it is refused instead of racing the first for its
files."""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


def check_writable(folder: Path | str, flag: str, beside: bool = False) -> None:
    """Refuses, in one line naming `flag` and the folder, a `folder` that cannot be made or written in: the
    nearest existing one of it and its parents (of its parent, for an output written `beside` it first and
    renamed into place) must be a folder this process can create files in."""
    path = Path(folder).expanduser().absolute()
    start = path.parent if beside else path
    existing = next(p for p in (start, *start.parents) if p.exists())
    if not existing.is_dir():
        raise ValueError(f"{flag} {folder}: {existing} is a file, not a folder")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as err:
        raise ValueError(
            f"{flag} {folder}: cannot write in {existing} ({err.strerror}); choose a folder you can write to"
        ) from None


@contextlib.contextmanager
def used_alone(folder: Path | str, flag: str) -> Iterator[None]:
    """Holds `folder` for this process while the block runs (a lock file beside it, released when the
    process ends however it ends); another process holding it is one line naming `flag` and its pid."""
    folder = Path(folder).expanduser().absolute()
    folder.parent.mkdir(parents=True, exist_ok=True)
    with open(folder.parent / f".{folder.name}.in_use", "a+") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            lock.seek(0)
            raise ValueError(
                f"{flag} {folder} is in use by another run ({lock.read().strip() or 'pid unknown'}); wait "
                "for it to end, or give another folder"
            ) from None
        lock.seek(0)
        lock.truncate()
        lock.write(f"pid {os.getpid()}")
        lock.flush()
        yield
