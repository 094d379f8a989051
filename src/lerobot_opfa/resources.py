"""Where the files shipped beside the code live: `hand_models/` and `checkpoints/` of the source tree
(editable installs) or their copies packed into the wheel."""

from __future__ import annotations

import difflib
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent


def resource_dir(name: str) -> Path:
    packaged = PACKAGE_DIR / name
    return packaged if packaged.is_dir() else PACKAGE_DIR.parents[1] / name


def builtin_or_path(
    kind: str, name: str | Path, builtins: dict[str, Path], in_folder: str | None = None
) -> Path:
    """The spec of built-in `kind` `name`, or the spec file `name` names (or, with `in_folder`, a folder
    holding it); neither is one line naming the built-ins, and the closest one."""
    if str(name) in builtins:
        return builtins[str(name)]
    path = Path(name)
    if in_folder and path.is_dir():
        path = path / in_folder
    if path.is_file():
        return path
    if path.suffix in (".yaml", ".yml") or len(path.parts) > 1:
        raise ValueError(f"{kind} spec {path} not found (the built-in {kind}s: {', '.join(builtins)})")
    closest = difflib.get_close_matches(str(name), builtins, n=1)
    hint = f" (did you mean '{closest[0]}'?)" if closest else ""
    what = in_folder or "spec"
    raise ValueError(
        f"unknown {kind} '{name}'{hint}: not a built-in ({', '.join(builtins)}) and not a {what} path"
    )
