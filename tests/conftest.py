"""Shared fixtures: the built-in hands, and user hands made from third-party models with meshes: URDFs
(example-robot-data's Allegro, dexi-rs' Fourier hand) and an MJCF (gymnasium-robotics' Shadow hand), as
their packages ship them."""

from __future__ import annotations

import importlib.util
import logging
import os
import re
import shutil
import sysconfig
from pathlib import Path

# No test reaches the network (`make test` sets these too); set before anything imports huggingface_hub.
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("MUJOCO_GL", "egl")

import pytest  # noqa: E402
import yaml  # noqa: E402

import lerobot_policy_opfa  # noqa: E402, F401  (the plugin, as LeRobot loads it: steps, robot_type)
from lerobot_opfa.hands.registry import builtin_hands, hand_models_dir  # noqa: E402

if os.environ.get("PYTEST_XDIST_WORKER"):
    # `make test` runs a worker per core: one torch thread each, here and in the processes tests start
    # (torch's spinning OpenMP threads collapse on oversubscribed cores).
    import torch

    os.environ["OMP_NUM_THREADS"] = "1"
    torch.set_num_threads(1)

LONGEST_FIRST = (
    "test_experiments.py", "test_any_lerobot_policy.py", "test_rig.py", "test_policy.py",
    "test_user_hands.py", "test_distributed.py", "test_training_fast.py", "test_depth.py",
    "test_refusals_checkpoints.py", "test_guards.py",
)  # fmt: skip
"""The files that take longest (they run LeRobot's commands), by their measured durations."""


def pytest_collection_modifyitems(items):
    """The longest files first: `make test` gives each file to one worker, in this order, and a long file
    started last would keep one worker busy while the other idles."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


DATA = Path(__file__).parent / "data"
BUILTIN_HANDS = sorted(builtin_hands())


@pytest.fixture(autouse=True)
def _root_logging_as_it_was():
    """LeRobot's training entry point, run in process, adds a root handler on the test's captured stderr,
    which is closed once the test ends; later tests would log into it."""
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)


def example_robot_data_allegro() -> Path:
    """The Allegro URDF (with STL meshes) installed by the PyPI package example-robot-data."""
    share = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data"
    urdf = share / "robots" / "allegro_hand_description" / "urdf" / "allegro_right_hand.urdf"
    if not urdf.is_file():
        pytest.fail(f"example-robot-data's Allegro URDF not found at {urdf}; install the [test] extra")
    return urdf


def vendor_spec(tmp_path: Path, name: str, model: Path) -> Path:
    """tests/data/NAME/spec.yaml with the vendor's installed model file as its `model`, in a folder of its
    own (to be edited by the test)."""
    spec = tmp_path / name / "spec.yaml"
    spec.parent.mkdir()
    spec.write_text((DATA / name / "spec.yaml").read_text().replace("MODEL_PATH", str(model)))
    return spec


def installed_package(module: str, package: str) -> Path:
    """The folder of the installed PyPI package `package` (import name `module`) that holds vendor files."""
    found = importlib.util.find_spec(module)
    if found is None:
        pytest.fail(f"{package} is not installed; install the [test] extra")
    return Path(found.submodule_search_locations[0])


@pytest.fixture
def user_allegro_spec(tmp_path: Path) -> Path:
    return vendor_spec(tmp_path, "user_allegro", example_robot_data_allegro())


@pytest.fixture
def cad_like_allegro_spec(tmp_path: Path) -> Path:
    """example-robot-data's Allegro as a CAD export writes a hand: links named after parts (`part_17_d3`),
    visual meshes only, and a spec that names the actuated joints and nothing of the links: a stand-in for
    a CAD export beside the real one (orca_arm's Onshape export, `user_orca_spec`)."""
    urdf = example_robot_data_allegro()
    share = urdf.parents[3]  # .../share/example-robot-data: what package://example-robot-data/ names
    text = re.sub(r"<collision>.*?</collision>", "", urdf.read_text(), flags=re.S)
    links = re.findall(r'<link name="([^"]+)"', text)
    for index, link in enumerate(links):
        part = f"part_{17 + 3 * index}_d{index % 4}"
        text = re.sub(rf'(<link name=|<parent link=|<child link=)"{re.escape(link)}"', rf'\1"{part}"', text)
    model = tmp_path / "cad_allegro" / "allegro.urdf"
    model.parent.mkdir()
    model.write_text(text.replace("package://example-robot-data/", f"{share}/"))
    raw = yaml.safe_load((DATA / "user_allegro" / "spec.yaml").read_text())
    raw.pop("links")
    raw.update(name="cad_allegro", model=str(model))
    spec = model.parent / "spec.yaml"
    spec.write_text(yaml.safe_dump(raw, sort_keys=False))
    return spec


def dexi_rs_fourier() -> Path:
    """The Fourier 6-DoF right hand URDF (with STL meshes) installed by the PyPI package dexi-rs."""
    hands = installed_package("dexi_rs", "dexi-rs") / "resources" / "assets" / "robots" / "hands"
    return hands / "fourier_hand" / "base_urdf" / "fourier_right_hand_6dof.urdf"


@pytest.fixture
def user_fourier_spec(tmp_path: Path) -> Path:
    return vendor_spec(tmp_path, "user_fourier", dexi_rs_fourier())


def orca_arm_urdf() -> Path:
    """The bimanual OpenArm URDF with two ORCA hands (STL meshes) installed by the PyPI package orca_arm."""
    return installed_package("orca_arm", "orca_arm") / "orcabot.urdf"


@pytest.fixture
def user_orca_spec(tmp_path: Path) -> Path:
    return vendor_spec(tmp_path, "user_orca", orca_arm_urdf())


def gymnasium_robotics_assets() -> Path:
    return installed_package("gymnasium_robotics", "gymnasium-robotics") / "envs" / "assets"


@pytest.fixture
def user_shadow_spec(tmp_path: Path) -> Path:
    """The Shadow MJCF with its meshes (copied, to write the wrapper beside it) and a spec for it."""
    assets = gymnasium_robotics_assets()
    shutil.copytree(assets / "hand", tmp_path / "assets" / "hand")
    shutil.copytree(assets / "stls" / "hand", tmp_path / "assets" / "stls" / "hand")
    wrapper = tmp_path / "assets" / "hand" / "shadow_hand.xml"
    shutil.copy(DATA / "user_shadow_mjcf" / "shadow_hand.xml", wrapper)
    spec = tmp_path / "user_shadow" / "spec.yaml"
    spec.parent.mkdir()
    spec.write_text((DATA / "user_shadow_mjcf" / "spec.yaml").read_text().replace("MODEL_PATH", str(wrapper)))
    return spec


@pytest.fixture
def umi_copy(tmp_path: Path) -> Path:
    """A writable copy of the UMI gripper folder, for specs broken on purpose."""
    target = tmp_path / "umi"
    shutil.copytree(hand_models_dir() / "umi", target)
    return target
