"""Where the files shipped beside the code live: `hand_models/` and `checkpoints/` of the source tree
(editable installs) or their copies packed into the wheel."""

from __future__ import annotations

from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent


def resource_dir(name: str) -> Path:
    packaged = PACKAGE_DIR / name
    return packaged if packaged.is_dir() else PACKAGE_DIR.parents[1] / name


def default_galr_checkpoint() -> Path:
    """The GaLR checkpoint trained on all built-in hands by the documented CPU command (see README)."""
    return resource_dir("checkpoints") / "galr_default"


def long_galr_checkpoint() -> Path:
    """The most accurate packaged GaLR checkpoint (135 CPU minutes; see README)."""
    return resource_dir("checkpoints") / "galr_long"
