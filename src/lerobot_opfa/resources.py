"""Where the files shipped beside the code live: `hand_models/` and `checkpoints/` of the source tree
(editable installs) or their copies packed into the wheel."""

from __future__ import annotations

from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent


def resource_dir(name: str) -> Path:
    packaged = PACKAGE_DIR / name
    return packaged if packaged.is_dir() else PACKAGE_DIR.parents[1] / name
