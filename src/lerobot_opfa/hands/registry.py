"""Which hands exist: the built-in models shipped in `hand_models/` plus any spec a user names."""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING

from lerobot_opfa.hands.spec import HandSpec, HandSpecError
from lerobot_opfa.resources import builtin_or_path, resource_dir

if TYPE_CHECKING:
    from lerobot_opfa.hands.model import HandModel


def hand_models_dir() -> Path:
    return resource_dir("hand_models")


def builtin_hands() -> dict[str, Path]:
    """Built-in hand name -> spec path."""
    return {p.parent.name: p for p in sorted(hand_models_dir().glob("*/spec.yaml"))}


def resolve_spec_path(hand: str | Path) -> Path:
    """A built-in name or a path to a `spec.yaml` (or a folder holding one)."""
    return builtin_or_path("hand", hand, builtin_hands(), "spec.yaml")


def hand_ref(spec: HandSpec) -> str:
    """What `load_hand` takes for this spec: the built-in's name when it is the built-in's file, else its
    path (a user hand, even one named like a built-in)."""
    builtin = builtin_hands().get(spec.name)
    return spec.name if builtin is not None and builtin.resolve() == spec.path else str(spec.path)


def load_spec(hand: str | Path) -> HandSpec:
    """The spec of a built-in name or a spec path; a user spec that takes a built-in's name must be that
    built-in (same sha256), or datasets and GaLR checkpoints could not tell the two apart."""
    spec = HandSpec.load(resolve_spec_path(hand))
    builtin = builtin_hands().get(spec.name)
    if (
        builtin is not None
        and builtin.resolve() != spec.path
        and HandSpec.load(builtin).sha256 != spec.sha256
    ):
        raise HandSpecError(
            spec.path,
            "name",
            f"'{spec.name}' is a built-in hand's name, but this spec or its model differs from the built-in "
            f"({builtin}); give the hand a name of its own (e.g. 'my_{spec.name}')",
        )
    return spec


@cache
def _load_hand_cached(spec_path: Path, device: str, modified: int) -> HandModel:
    from lerobot_opfa.hands.model import HandModel  # torch and the model parsers: only when a model is built

    return HandModel.from_spec(spec_path, device=device)


def load_hand(hand: str | Path, device: str = "cpu") -> HandModel:
    """A `HandModel` for a built-in name or a spec path; parsed models are cached per process (until the
    spec file changes)."""
    path = load_spec(hand).path
    return _load_hand_cached(path, str(device), path.stat().st_mtime_ns)
