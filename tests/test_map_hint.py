"""The closest-hand hint of a dataset whose entries match no hand: hand joints proposed only for entries that
name their finger, one slot per side of a two-armed robot, hands of one structure told apart by names and
recorded ranges, and the units of entries recorded in degrees or 0..1000."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.utils.constants import ACTION, OBS_STATE
from test_joint_maps import ARM, GHAND_FINGERS, INSPIRE, N_POINTS, inspire_units, robot_dataset

from lerobot_opfa import cli
from lerobot_opfa.datasets.io import read_columns
from lerobot_opfa.datasets.joint_map import JointMap
from lerobot_opfa.datasets.layout import JointNameError, identify_hand, read_layout
from lerobot_opfa.datasets.map_hint import motor_units, sense_undecided, units_from_range
from lerobot_opfa.datasets.synthetic import write_synthetic_dataset
from lerobot_opfa.hands import load_hand
from lerobot_opfa.hands.model import LIMIT_TOLERANCE
from lerobot_opfa.hands.registry import load_spec

G1_ARM = ("ShoulderPitch", "ShoulderRoll", "ShoulderYaw", "Elbow", "WristRoll", "WristPitch", "WristYaw")
DEX3 = ("Thumb0", "Thumb1", "Thumb2", "Middle0", "Middle1", "Index0", "Index1")
G1_INSPIRE = ("Pinky", "Ring", "Middle", "Index", "ThumbBend", "ThumbRotation")
SO101 = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
FINGER_OF = {"pinky": "little", "thumb": "thumb", "index": "index", "middle": "middle", "ring": "ring"}


def g1_names(hand: tuple[str, ...]) -> list[str]:
    """A Unitree G1's arms, then a hand on each (`kLeftHandThumb0`), as its SDK names its motors."""
    return [
        *(f"k{side}{joint}" for side in ("Left", "Right") for joint in G1_ARM),
        *(f"k{side}Hand{joint}" for side in ("Left", "Right") for joint in hand),
    ]


def features_of(names: list[str]) -> dict:
    return {key: {"dtype": "float32", "shape": (len(names),), "names": names} for key in (OBS_STATE, ACTION)}


def proposed_maps(message: str) -> dict[str | None, dict]:
    """The hands of the joint map the error proposes, by side (None: a one-handed robot), and (key "map")
    the whole map."""
    proposed = yaml.safe_load(message[message.index("to check line by line:\n") :].split("\n", 1)[1])
    if "slots" not in proposed:
        return {None: proposed, "map": proposed}
    return {slot.pop("side"): slot for slot in [dict(s) for s in proposed["slots"]]} | {"map": proposed}


def hint(features: dict, robot_type: str, root: Path | None = None) -> str:
    with pytest.raises(JointNameError) as error:
        read_layout(features, robot_type, root)
    return str(error.value)


def identify_hand_error(names: list[str]) -> str:
    """The map an unknown robot's names get, as printed."""
    with pytest.raises(JointNameError) as error:
        identify_hand(names, None)
    return str(error.value).split("to check line by line:\n", 1)[1]


@pytest.mark.parametrize("hand", [DEX3, G1_INSPIRE], ids=["dex3", "inspire"])
def test_a_two_armed_robot_gets_a_slot_per_side_of_its_hand_entries_only(hand):
    names = g1_names(hand)
    maps = proposed_maps(hint(features_of(names), "g1"))
    whole = maps.pop("map")
    assert set(maps) == {"left", "right"}
    if hand == G1_INSPIRE:
        JointMap.from_dict(whole).bind(names, names)  # the proposal is a map as it stands
    for side, proposed in maps.items():
        spec = load_spec(proposed["hand"])
        hand_entries = {f"k{side.title()}Hand{joint}" for joint in hand}
        assert proposed["joints"] and set(proposed["joints"]) <= hand_entries, "never an arm's entry"
        for entry, joint in proposed["joints"].items():
            finger = FINGER_OF[re.match(r"k\w+?Hand([A-Z][a-z]+)", entry).group(1).lower()]
            assert spec.joints[joint].startswith(finger), f"{entry} -> {joint}"
        if hand == G1_INSPIRE:
            assert proposed["hand"] == "inspire"
            assert proposed["joints"][f"k{side.title()}HandThumbRotation"] == "thumb_yaw"
            assert proposed["joints"][f"k{side.title()}HandThumbBend"] == "thumb_bend"
            assert proposed["joints"][f"k{side.title()}HandPinky"] == "little_mcp_flex"


def test_a_bimanual_arms_gripper_entries_go_to_a_gripper_and_its_arm_entries_nowhere():
    names = [f"{side}_{joint}.pos" for side in ("left", "right") for joint in SO101]
    maps = proposed_maps(hint(features_of(names), "bi_so101_follower"))
    JointMap.from_dict(maps.pop("map")).bind(names, names)
    assert set(maps) == {"left", "right"}
    for side, proposed in maps.items():
        spec = load_spec(proposed["hand"])
        assert spec.kind == "gripper"
        assert proposed["joints"] == {f"{side}_gripper.pos": spec.actuated_joints[0]}


@pytest.fixture(scope="module")
def robots(tmp_path_factory) -> Path:
    """A LEAP plugin's dataset (16 `right_hand.*.pos` entries) in radians and in degrees, and an arm with an
    Inspire hand whose actuators read 0..1000, written from synthetic datasets of the two hands."""
    root = tmp_path_factory.mktemp("robots")
    write_synthetic_dataset(root / "leap_sim", "leap", episodes=2, frames=12, n_points=N_POINTS, seed=3)
    write_synthetic_dataset(root / "inspire_sim", "inspire", episodes=2, frames=12, n_points=N_POINTS, seed=4)
    robot_dataset(root / "leap_sim", root / "ghand", "ghand", GHAND_FINGERS, {}, body=[])
    degrees = {joint: (math.pi / 180, 0.0) for joint in GHAND_FINGERS.values()}
    robot_dataset(root / "leap_sim", root / "ghand_degrees", "ghand", GHAND_FINGERS, degrees, body=[])
    robot_dataset(root / "inspire_sim", root / "arm_inspire", "arm_inspire", INSPIRE, inspire_units(), ARM)
    return root


def test_a_leap_plugins_entries_get_leap_first_and_a_map_that_merges(robots, tmp_path, capsys):
    names = list(GHAND_FINGERS)
    tie = identify_hand_error(names)  # LEAP and Allegro: the same joints under the same names
    assert tie.startswith("hand: allegro  # or leap")
    assert yaml.safe_load(tie)["joints"] == GHAND_FINGERS
    branded = [n.replace("right_hand.", "leap_hand.") for n in names]
    assert identify_hand_error(branded).startswith("hand: leap\n"), "a name that says the hand"
    merge = ["dataset", "merge", "--inputs", str(robots / "ghand")]
    assert cli.main([*merge, "--output", str(tmp_path / "m")]) == 2
    err = capsys.readouterr().err
    assert "closest by joint structure and names: 'leap' (16 joints" in err  # its ranges fit LEAP's limits
    suggested = err[err.index("hand: leap") :].strip()
    assert yaml.safe_load(suggested) == {"hand": "leap", "joints": GHAND_FINGERS}  # radians: no scale
    (tmp_path / "suggested.yaml").write_text(suggested + "\n")
    joint_maps = ["--joint-maps", str(tmp_path / "suggested.yaml")]
    assert cli.main([*merge, "--output", str(tmp_path / "m"), *joint_maps]) == 0
    merged = read_columns(tmp_path / "m", [OBS_STATE])[OBS_STATE]
    sim = read_columns(robots / "leap_sim", [OBS_STATE])[OBS_STATE]
    universal = load_hand("leap").to_universal(torch.tensor(sim[:, 6:], dtype=torch.float32)).numpy()
    assert np.allclose(merged[:, : universal.shape[1]], universal, atol=1e-6), "the merge reads the map"


def test_entries_in_degrees_or_0_to_1000_get_the_scale_into_the_joint_limits(robots):
    assert units_from_range((0.0, 90.0), (0.0, 1.57)) == pytest.approx((math.pi / 180, 0.0))
    assert units_from_range((0.0, 1000.0), (0.0, 1.57)) == pytest.approx((0.00157, 0.0))
    assert units_from_range((0.0, -1.5), (0.0, 1.5)) == (-1.0, 0.0)  # a sign only where the ranges say it
    assert units_from_range((0.1, 1.2), (0.0, 1.57)) is None
    for dataset, hand in (("ghand_degrees", "leap"), ("arm_inspire", "inspire")):
        meta = LeRobotDatasetMetadata(f"local/{dataset}", root=robots / dataset)
        message = hint(meta.features, meta.robot_type, robots / dataset)
        assert "inferred from the recorded ranges" in message
        proposed = proposed_maps(message)[None]
        assert proposed["hand"] == hand
        model, ranges = load_hand(hand), read_columns(robots / dataset, [OBS_STATE])[OBS_STATE]
        names = meta.features[OBS_STATE]["names"]
        for entry, mapped in proposed["joints"].items():
            values = mapped["scale"] * ranges[:, names.index(entry)] + mapped["offset"]
            i = model.joint_names.index(mapped["joint"])
            low, high = float(model.lower[i]), float(model.upper[i])
            slack = LIMIT_TOLERANCE * (high - low)
            assert low - slack <= values.min() and values.max() <= high + slack, entry
            if dataset == "ghand_degrees":
                assert mapped["scale"] == pytest.approx(math.pi / 180, rel=1e-5) and mapped["offset"] == 0
        assert len(proposed["joints"]) == len(model.joint_names)


def test_a_sense_or_units_the_recorded_ranges_cannot_decide_are_told_apart():
    assert sense_undecided((-0.3, 0.4), (-1.0, 1.0))  # a mirrored joint reads either way
    assert not sense_undecided((0.1, 1.2), (0.0, 1.57)) and not sense_undecided((0.0, -1.5), (0.0, 1.5))
    assert not sense_undecided((0.2, 0.2), (-1.0, 1.0))  # an entry that never moves says nothing
    assert motor_units([(0.25, 1.0), (0.0, 0.7)])  # every entry within 0..1, held at an end
    assert not motor_units([(0.25, 0.9), (0.1, 0.7)]) and not motor_units([(0.0, 1.4)])
