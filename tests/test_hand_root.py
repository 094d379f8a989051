"""A model file that holds more than the hand (an arm, a second hand, a forearm with a wrist) is cut to the
subtree below the spec's `root` link (URDF) or body (MJCF): the rest is never loaded, and the hand keeps the
geometry it has in the whole model."""

from __future__ import annotations

import pytest
import pytorch_kinematics as pk
import torch
import yaml
from conftest import orca_arm_urdf

from lerobot_opfa.cli import main
from lerobot_opfa.hands import load_hand
from lerobot_opfa.hands.validate import fk_error_vs_mujoco


def test_the_orca_hand_is_cut_out_of_its_bimanual_robot_as_it_sits_there(user_orca_spec):
    hand = load_hand(user_orca_spec)
    robot = pk.build_chain_from_urdf(orca_arm_urdf().read_bytes()).to(dtype=torch.float64)
    assert len(robot.get_joint_parameter_names()) == 44  # two arms, two wrists, two hands
    assert len(hand.chain_joint_names) == 16 and all(
        j.startswith("orcahand_right_") for j in hand.chain_joint_names
    )
    assert len(hand.link_names) == 17 and all(link.startswith("orcahand_right_") for link in hand.link_names)

    q = hand.sample_joints(4, torch.Generator().manual_seed(0)).double()
    full = torch.zeros(len(q), len(robot.get_joint_parameter_names()), dtype=torch.float64)
    full[:, [robot.get_joint_parameter_names().index(j) for j in hand.chain_joint_names]] = hand.expand(
        q.float()
    ).double()
    in_robot = robot.forward_kinematics(full)
    root = in_robot[load_hand(user_orca_spec).spec.root].get_matrix()
    expected = torch.stack(
        [torch.linalg.inv(root) @ in_robot[link].get_matrix() for link in hand.link_names], 1
    )
    assert torch.allclose(hand.forward_kinematics(q.float()).double(), expected, atol=1e-5)
    assert max(fk_error_vs_mujoco(hand, q.float())) < 1e-5


def test_a_vendor_mjcf_cut_at_the_palm_needs_no_held_wrist(user_shadow_spec):
    """gymnasium-robotics' Shadow with its forearm and two wrist joints: `root` at the palm drops them, and
    the hand's links lie where the spec that holds the wrist puts them."""
    held = load_hand(user_shadow_spec)
    raw = yaml.safe_load(user_shadow_spec.read_text())
    raw.update(name="gym_shadow_palm", root="robot0:palm")
    for field in ("fixed", "links"):
        raw.pop(field)
    cut_spec = user_shadow_spec.with_name("cut.yaml")
    cut_spec.write_text(yaml.safe_dump(raw, sort_keys=False))
    cut = load_hand(cut_spec)
    assert "robot0:WRJ0" not in cut.chain_joint_names and "robot0:forearm" not in cut.link_names
    assert cut.joint_names == held.joint_names
    shared = [held.link_names.index(link) for link in cut.link_names]
    q = held.sample_joints(4, torch.Generator().manual_seed(0))
    assert torch.allclose(cut.forward_kinematics(q), held.forward_kinematics(q)[:, shared], atol=1e-5)
    assert max(fk_error_vs_mujoco(cut, q)) < 1e-5


@pytest.mark.parametrize("root", ["orcahand_right_wrist", "openarm_right_link5"])
def test_a_root_that_is_not_the_hands_is_one_line_naming_the_field(user_orca_spec, root, capsys):
    raw = yaml.safe_load(user_orca_spec.read_text())
    raw["root"] = root
    user_orca_spec.write_text(yaml.safe_dump(raw))
    assert main(["hands", "check", str(user_orca_spec)]) != 0
    (line,) = capsys.readouterr().err.strip().splitlines()[-1:]
    if root == "openarm_right_link5":  # above the wrist, which the spec then has to describe
        assert "model joint(s) ['orcahand_right_R-Carpals_8d1f1041_to_TopTower-Model_4a80d30e'] are " in line
    else:
        assert f"no link '{root}' (the spec's `root`)" in line, line
