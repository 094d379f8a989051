"""A user's hand as one archive: its spec, its model file and every file the model reads, so that a checkpoint
trained on it carries the hand (a spec path names a file on the machine that trained it; moved, shared on
the Hub or with the spec deleted, the checkpoint could not be loaded).

The archive keeps the files' layout under their common folder, the spec naming the model by its place there,
and a URDF's mesh paths made relative to it (`package://` and absolute paths name another machine's files).
It is unpacked once per content into the Hugging Face cache, where `load_hand` reads it like any spec.
"""

from __future__ import annotations

import hashlib
import io
import os
import re
import tarfile
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

from lerobot_opfa.hands.spec import HandSpec
from lerobot_opfa.yaml_files import read_yaml

USER_HAND = "user_hand."
"""State-dict key prefix of a user hand's archive in a checkpoint's processor state, by the hand's name."""
SPEC = "spec.yaml"
MODEL = "model"
"""The archive's folder of the model file and what it reads."""


def hands_cache() -> Path:
    """Where unpacked hands live: `lerobot_opfa/hands/<digest>` in the Hugging Face cache (HF_HOME)."""
    from huggingface_hub import constants

    return Path(constants.HF_HOME) / "lerobot_opfa" / "hands"


def pack(spec_path: str | Path) -> bytes:
    """The archive (an uncompressed tar, the same bytes for the same files) of the hand `spec_path` names."""
    spec = HandSpec.load(spec_path)
    model = spec.model_path
    text = model.read_bytes()
    if model.suffix.lower() == ".urdf":
        text, files = _urdf_relative(text.decode(), model)
        text = text.encode()
    else:
        files = _mjcf_files(model)
    root = Path(os.path.commonpath([model.parent, *(f.parent for f in files)]))
    raw = read_yaml(spec.path, "hand spec")
    raw["model"] = f"{MODEL}/{model.relative_to(root).as_posix()}"
    members = {SPEC: yaml.safe_dump(raw, sort_keys=False).encode(), raw["model"]: text}
    for file in sorted(set(files) - {model}):
        members[f"{MODEL}/{file.relative_to(root).as_posix()}"] = file.read_bytes()
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.PAX_FORMAT) as tar:
        for name, data in sorted(members.items()):
            info = tarfile.TarInfo(name)
            info.size, info.mode = len(data), 0o644
            tar.addfile(info, io.BytesIO(data))
    return buffer.getvalue()


def unpack(data: bytes) -> Path:
    """The spec of the hand archive `data`, unpacked into `hands_cache()` unless it is there already."""
    folder = hands_cache() / hashlib.sha256(data).hexdigest()[:24]
    if not (folder / SPEC).is_file():
        partial = folder.with_name(f".{folder.name}.partial-{os.getpid()}")
        with tarfile.open(fileobj=io.BytesIO(data)) as tar:
            tar.extractall(partial, filter="data")
        try:
            partial.rename(folder)
        except OSError:  # another process unpacked the same hand first
            if not (folder / SPEC).is_file():
                raise
            _remove(partial)
    return folder / SPEC


def carried_hand(name: str, state_files: list[Path]) -> str:
    """`name` itself, or where it is neither a built-in hand nor a spec path, the user hand of that name that
    a checkpoint's processor `state_files` carry, unpacked: a checkpoint moved to another machine brings its
    hand, whose spec is not there."""
    from lerobot_opfa.hands.registry import builtin_hands

    if name in builtin_hands() or Path(name).exists():
        return name
    from safetensors import safe_open

    for state in state_files:
        with safe_open(state, "pt") as tensors:
            if f"{USER_HAND}{name}" in tensors.keys():
                return str(unpack(tensors.get_tensor(f"{USER_HAND}{name}").numpy().tobytes()))
    return name


def _remove(folder: Path) -> None:
    import shutil

    shutil.rmtree(folder, ignore_errors=True)


def _urdf_relative(text: str, model: Path) -> tuple[str, list[Path]]:
    """The URDF with every file it names (meshes, textures) as a path relative to it, and those files."""
    from lerobot_opfa.hands.geometry import resolve_urdf_mesh

    files: list[Path] = []

    def relative(match: re.Match) -> str:
        try:
            file = resolve_urdf_mesh(match[2], model)
        except FileNotFoundError:
            return match[0]  # left to the model's own check, which names it
        files.append(file)
        return f"filename={match[1]}{Path(os.path.relpath(file, model.parent)).as_posix()}{match[1]}"

    return re.sub(r"filename=([\"'])(.*?)\1", relative, text), files


def _mjcf_files(model: Path) -> list[Path]:
    """The MJCF's included files (each relative to its includer, else to the model's folder) and the meshes,
    textures, height fields and skins they load."""
    import mujoco

    files, pending = [], [model]
    while pending:
        current = pending.pop()
        for element in ET.parse(current).getroot().iter("include"):
            candidates = [current.parent / element.get("file", ""), model.parent / element.get("file", "")]
            found = next((c.resolve() for c in candidates if c.is_file()), None)
            if found is not None and found not in files:
                files.append(found)
                pending.append(found)
    spec = mujoco.MjSpec.from_file(str(model))
    folders = {"meshes": spec.meshdir, "textures": spec.texturedir, "hfields": "", "skins": ""}
    for kind, folder in folders.items():
        for asset in getattr(spec, kind):
            if asset.file:
                file = (model.parent / (folder or "") / asset.file).resolve()
                if file.is_file():
                    files.append(file)
    return files
