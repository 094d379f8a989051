"""Output folders checked before any work: one that cannot be written would otherwise fail only at the end
(a training run's first checkpoint, a dataset's final rename), as an OSError traceback."""

from __future__ import annotations

import tempfile
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
