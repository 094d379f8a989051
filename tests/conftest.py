"""Shared fixtures: the built-in hands, and a user hand made from a third-party URDF with meshes."""

from __future__ import annotations

import shutil
import sysconfig
from pathlib import Path

import pytest

from lerobot_opfa.hands.registry import builtin_hands, hand_models_dir

DATA = Path(__file__).parent / "data"
BUILTIN_HANDS = sorted(builtin_hands())


def example_robot_data_allegro() -> Path:
    """The Allegro URDF (with STL meshes) installed by the PyPI package example-robot-data."""
    share = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data"
    urdf = share / "robots" / "allegro_hand_description" / "urdf" / "allegro_right_hand.urdf"
    if not urdf.is_file():
        pytest.fail(f"example-robot-data's Allegro URDF not found at {urdf}; install the [test] extra")
    return urdf


@pytest.fixture
def user_allegro_spec(tmp_path: Path) -> Path:
    spec = tmp_path / "user_allegro" / "spec.yaml"
    spec.parent.mkdir()
    spec.write_text(
        (DATA / "user_allegro" / "spec.yaml")
        .read_text()
        .replace("MODEL_PATH", str(example_robot_data_allegro()))
    )
    return spec


@pytest.fixture
def umi_copy(tmp_path: Path) -> Path:
    """A writable copy of the UMI gripper folder, for specs broken on purpose."""
    target = tmp_path / "umi"
    shutil.copytree(hand_models_dir() / "umi", target)
    return target
