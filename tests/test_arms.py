"""Arm specs: the built-in arms (example-robot-data's UR5 and Franka Panda, as they ship) and a user's MJCF
arm read into chains whose FK agrees with MuJoCo's, the hand's wrist placed through base and mount, the
mounted hand's reach over the table, and a spec that cannot describe its model refused in one line."""

from __future__ import annotations

import math

import pytest
import torch

from lerobot_opfa import cli
from lerobot_opfa.arms.check import FK_TOLERANCE, fk_error_vs_mujoco, reach, sample_joints
from lerobot_opfa.arms.spec import ArmSpec, builtin_arms, load_arm, transform
from lerobot_opfa.hands.registry import load_hand

TWO_LINK_MJCF = """<mujoco><worldbody><body name="link1" pos="0 0 0.1">
  <joint name="j1" type="hinge" axis="0 0 1" range="-2 2"/>
  <geom type="capsule" size="0.02" fromto="0 0 0 0.3 0 0"/>
  <body name="link2" pos="0.3 0 0" euler="0.3 0 0">
    <joint name="j2" type="hinge" axis="0 1 0" range="-1.5 1.5"/>
    <geom type="capsule" size="0.02" fromto="0 0 0 0.25 0 0"/><body name="flange" pos="0.25 0 0.01"/></body>
</body></worldbody></mujoco>"""


def user_arm(tmp_path, **fields) -> ArmSpec:
    (tmp_path / "two_link.xml").write_text(TWO_LINK_MJCF)
    raw = {"name": "two_link", "model": "two_link.xml", "flange": "flange", "joints": ["j1", "j2"]} | fields
    lines = [f"{key}: {value}" for key, value in raw.items()]
    (tmp_path / "arm.yaml").write_text("\n".join(lines).replace("'", '"') + "\n")
    return ArmSpec.load(tmp_path / "arm.yaml")


@pytest.mark.parametrize("name", ["ur5", "panda"])
def test_each_built_in_arms_fk_agrees_with_mujoco_and_its_hand_reaches_every_region(name):
    spec = load_arm(name)
    chain = spec.chain()
    position, rotation = fk_error_vs_mujoco(spec, chain, sample_joints(chain, 32))
    assert position < FK_TOLERANCE and rotation < FK_TOLERANCE, (position, rotation)
    assert all(reach(spec, chain, load_hand("umi")).reached)


def test_the_wrist_is_placed_through_base_and_mount_and_a_wrist_pose_gives_its_flange_target():
    spec = load_arm("ur5")
    chain = spec.chain()
    q = sample_joints(chain, 8, seed=1)
    wrist = spec.wrist_pose(chain, q)
    assert torch.allclose(spec.flange_target(wrist), chain.flange_pose(q), atol=1e-12)
    home = spec.wrist_pose(chain, torch.tensor([spec.home]))[0]
    assert torch.allclose(home[:3, 3], torch.tensor([-0.05, 0.0, 0.30], dtype=torch.float64), atol=2e-3)
    assert home[2, 2] < -0.999, "at home the fingers (+z of the wrist frame) point down"


def test_a_users_mjcf_arm_reads_as_mujoco_reads_it(tmp_path):
    spec = user_arm(tmp_path, base="{xyz: [0.1, 0.0, 0.0], rpy: [0.0, 0.0, 0.5]}")
    chain = spec.chain()
    position, rotation = fk_error_vs_mujoco(spec, chain, sample_joints(chain, 16))
    assert position < FK_TOLERANCE and rotation < FK_TOLERANCE
    q = torch.zeros(1, 2, dtype=torch.float64)
    expected = transform([0.1, 0.0, 0.0], [0.0, 0.0, 0.5]) @ chain.flange_pose(q)[0]
    assert torch.allclose(spec.wrist_pose(chain, q)[0], expected)


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"flange": "tool9"}, r"field 'flange': .*flange body 'tool9' is not a body of the model"),
        ({"joints": "[j2, j1]"}, r"field 'joints': j2, j1; the model's chain to 'flange' has j1, j2"),
        ({"home": "[0.0, 3.0]"}, r"field 'home': j2 outside its limits"),
        ({"home": "[0.0]"}, r"field 'home': one value per joint \(2\)"),
        ({"model": "package://no-such-package/arm.urdf"}, r"is not installed .*install the PyPI package"),
        ({"mount": "{xyz: [0, 0]}"}, r"field 'mount.xyz': three numbers"),
        ({"reach": 1}, r"field 'reach': unknown field"),
    ],
)
def test_a_spec_that_cannot_describe_its_model_is_one_line_naming_the_field(
    tmp_path, capsys, fields, message
):
    def check() -> None:
        user_arm(tmp_path, **fields).chain()

    with pytest.raises(ValueError, match=message):
        check()
    assert cli.main(["arms", "check", str(tmp_path / "arm.yaml")]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 1 and errors[0].startswith("error:"), errors


def test_arms_list_and_check_on_the_command_line(tmp_path, capsys):
    assert cli.main(["arms", "list"]) == 0
    listed = capsys.readouterr().out
    assert all(name in listed for name in builtin_arms()) and "not installed" not in listed
    png = tmp_path / "ur5.png"
    assert cli.main(["arms", "check", "ur5", "--samples", "8", "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "reach with umi: 9/9 table regions" in out and png.stat().st_size > 10_000
    assert cli.main(["arms", "check", "ur6"]) == 2
    assert "did you mean 'ur5'" in capsys.readouterr().err
    assert math.isclose(load_arm("panda").base[0, 3].item(), -0.55)


@pytest.mark.parametrize(
    "mount", ["{xyz: [0, 0, 0], rpy: [3.14159, 0, 0]}", "{xyz: [0, 0, -0.15], rpy: [0, 0, 0]}"]
)
def test_a_mount_that_puts_the_hand_inside_the_arm_is_one_line(tmp_path, capsys, mount):
    """The UR5's spec with the hand turned back into the wrist, or set 15 cm behind the flange: refused where
    an arm is loaded for a hand (`arms check`, a joint map's arm), naming the field and the links."""
    from lerobot_opfa.arms.pose import ArmBody

    lines = builtin_arms()["ur5"].read_text().splitlines()
    spec = tmp_path / "ur5_backwards.yaml"
    spec.write_text("\n".join(f"mount: {mount}" if line.startswith("mount:") else line for line in lines))
    with pytest.raises(ValueError, match=r"field 'mount': it puts the inspire inside the arm .* of wrist_"):
        ArmBody.load(str(spec), load_hand("inspire"))
    assert cli.main(["arms", "check", str(spec), "--hand", "inspire", "--samples", "4"]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 1 and "inside the arm" in errors[0], errors
    for hand in ("umi", "inspire", "leap"):
        ArmBody.load("ur5", load_hand(hand))  # the built-in mount: clear of the arm
