"""Where a GaLR checkpoint comes from: a packaged name, a local folder, or a Hub repo id (`namespace/name`).

Anything else ends in one line saying what was looked for, never in a Hub lookup of a mistyped path."""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path
from typing import TYPE_CHECKING

from lerobot_opfa.resources import resource_dir

if TYPE_CHECKING:
    from lerobot_opfa.galr.model import Galr

PACKAGED = {
    "default": ("galr_default", "the paper's 11 hands; pretrained 55 CPU minutes; 0.83 deg mean joint RMSE"),
    "long": ("galr_long", "the paper's 11 hands; pretrained 135 CPU minutes; 1.09 deg mean joint RMSE"),
}
"""Name -> (folder under `checkpoints/`, what it is); errors from benchmarks/results/galr_*_eval.json."""
DEFAULT = "default"
"""What a `galr` policy uses when neither its flags nor its dataset name a checkpoint."""
CHECKPOINT_FILES = ("config.json", "model.safetensors")
HUB_REPO_ID = re.compile(r"[A-Za-z0-9][\w.-]*/[\w.-]+")


def packaged_path(name: str) -> Path:
    return resource_dir("checkpoints") / PACKAGED[name][0]


def resolve(ref: str | Path) -> str:
    """A packaged name -> its folder; an existing folder -> itself, if it holds a checkpoint; a
    `namespace/name` that is no local path -> the Hub repo id. Raises ValueError otherwise."""
    text = str(ref)
    if text in PACKAGED:
        return str(packaged_path(text))
    path = Path(text).expanduser()
    if path.exists():
        missing = [f for f in CHECKPOINT_FILES if not (path / f).is_file()]
        if missing:
            raise ValueError(f"{path} is not a GaLR checkpoint folder (it has no {' or '.join(missing)})")
        return str(path)
    if HUB_REPO_ID.fullmatch(text):
        return text
    raise ValueError(
        f"GaLR checkpoint '{text}' not found: not a packaged name ({', '.join(PACKAGED)}), "
        "not a folder, not a Hub repo id (namespace/name)"
    )


def record(ref: str | Path) -> str:
    """How to write `ref` down for later: a packaged name or Hub id as is, a folder as an absolute path."""
    source = resolve(ref)
    if str(ref) in PACKAGED or not Path(source).exists():
        return str(ref)
    return str(Path(source).resolve())


def load(ref: str | Path) -> Galr:
    """The checkpoint `ref` names (see `resolve`), in eval mode; a Hub failure is one ValueError line."""
    from lerobot_opfa.galr.model import Galr

    source = resolve(ref)
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # huggingface_hub prints "Loading weights from ..."
            return Galr.from_pretrained(source).eval()
    except OSError as err:  # huggingface_hub's errors (offline, missing repo or file) are OSErrors
        raise ValueError(
            f"GaLR checkpoint '{ref}': no such folder, and no Hub repo of that name could be fetched "
            f"({type(err).__name__}; offline, or no such repo)"
        ) from err


def listing() -> list[dict]:
    """The packaged checkpoints, for `lerobot-opfa galr list`: each with the hands its registry holds."""
    return [
        {
            "name": name,
            "path": str(packaged_path(name)),
            "description": description,
            "hands": [
                hand["name"]
                for hand in json.loads((packaged_path(name) / "config.json").read_text())["hands"]
            ],
        }
        for name, (_, description) in PACKAGED.items()
    ]
