"""A policy checkpoint folder's files as LeRobot saves them (`config.json`, the weights, each processor
pipeline's JSON and the state files its steps name), read where a checkpoint is judged before LeRobot loads
it: the env config at `--policy.path`, a folder copied in part."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from lerobot.utils.constants import POLICY_POSTPROCESSOR_DEFAULT_NAME, POLICY_PREPROCESSOR_DEFAULT_NAME

PREPROCESSOR, POSTPROCESSOR = (f"{name}.json" for name in (POLICY_PREPROCESSOR_DEFAULT_NAME,
                                                          POLICY_POSTPROCESSOR_DEFAULT_NAME))  # fmt: skip


def read(folder: Path | str | None, name: str) -> dict[str, Any] | None:
    """The JSON file `name` of the local checkpoint `folder`, or None (no folder, or no such file)."""
    path = Path(folder) / name if folder else None
    return json.loads(path.read_text()) if path is not None and path.is_file() else None


def steps(folder: Path | str | None, pipeline: str, registry_name: str | None = None) -> list[dict[str, Any]]:
    """The saved steps (`registry_name`, `config`, `state_file`) of the pipeline file `pipeline`; with
    `registry_name`, only the steps of that name."""
    saved = (read(folder, pipeline) or {}).get("steps", [])
    return [s for s in saved if registry_name in (None, s.get("registry_name"))]


def state_files(folder: Path | str | None) -> list[Path]:
    """The state files the checkpoint's processor steps name, preprocessor first (present or not)."""
    named = [
        s.get("state_file") for pipeline in (PREPROCESSOR, POSTPROCESSOR) for s in steps(folder, pipeline)
    ]
    return [Path(folder) / name for name in named if name]
