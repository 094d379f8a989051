"""MJCF hand models as vendors ship them: a model file with the pinned MuJoCo and pytorch-kinematics,
`<include>` fragments, and depth clouds that see geoms only (never a model's sites)."""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from lerobot_opfa import cli
from lerobot_opfa.envs.observation import DepthPointCloud
from lerobot_opfa.hands import load_hand
from lerobot_opfa.hands.validate import fk_error_vs_mujoco

JAWS = """
      <body name="left_jaw" pos="0 0.01 0.03">
        <joint name="left_jaw_joint" type="slide" axis="0 1 0" range="0 0.044"/>
        <geom type="box" size="0.014 0.005 0.05" pos="0 0 0.05"/>
      </body>
      <body name="right_jaw" pos="0 -0.01 0.03">
        <joint name="right_jaw_joint" type="slide" axis="0 -1 0" range="0 0.044"/>
        <geom type="box" size="0.014 0.005 0.05" pos="0 0 0.05"/>
      </body>"""
BASE = f"""<body name="base"><geom type="box" size="0.06 0.025 0.03"/>
      <body name="wrist_link" pos="0 0 0.03"><joint name="tilt" type="hinge" axis="1 0 0" range="-1 1"/>
        <geom type="box" size="0.01 0.01 0.01"/></body>{JAWS}
    </body>"""
GRIPPER = f'<mujoco model="gripper"><worldbody>{BASE}</worldbody></mujoco>'
SPEC = """name: mjcf_gripper
kind: gripper
model: {model}
description: a parallel-jaw gripper written in MJCF
joints:
  left_jaw_joint: gripper_aperture
couplings:
  right_jaw_joint: {{source: left_jaw_joint}}
  tilt: {{source: left_jaw_joint, scale: 0.0, offset: 0.0}}
links:
  base: [0, 0]
  wrist_link: [0, 0]
  left_jaw: [1, 0]
  right_jaw: [2, 0]
poses:
  open: {{left_jaw_joint: 0.044}}
  grasp: {{left_jaw_joint: 0.0}}
"""


def write_hand(folder, model_text: str, name: str = "gripper.xml"):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(model_text)
    (folder / "spec.yaml").write_text(SPEC.format(model=name))
    return folder / "spec.yaml"


def test_mjcf_hand_loads_with_fk_equal_to_mujoco(tmp_path, capsys):
    spec = write_hand(tmp_path / "hand", GRIPPER)
    hand = load_hand(spec)
    assert hand.dof == 1 and set(hand.chain_joint_names) == {"left_jaw_joint", "right_jaw_joint", "tilt"}
    position, rotation = fk_error_vs_mujoco(hand, hand.sample_joints(16, torch.Generator().manual_seed(0)))
    assert position < 1e-6 and rotation < 1e-6
    assert cli.main(["hands", "check", str(spec)]) == 0


def test_include_fragment_is_refused_with_a_wrapper_that_works(tmp_path, capsys):
    spec = write_hand(tmp_path / "hand", f"<mujocoinclude>{BASE}</mujocoinclude>", "fragment.xml")
    assert cli.main(["hands", "check", str(spec)]) == 2
    error = capsys.readouterr().err
    assert "a <mujocoinclude> fragment, not a model" in error
    wrapper = error[error.index("<mujoco model") : error.index("</mujoco>") + len("</mujoco>")]
    (tmp_path / "hand" / "wrapper.xml").write_text(wrapper)  # exactly what the error says to write
    assert load_hand(write_hand(tmp_path / "hand", wrapper, "wrapper.xml")).dof == 1


def test_depth_cloud_sees_geoms_not_sites():
    box = 'pos="0 0 0.05" size="0.03 0.03 0.05"'
    model = mujoco.MjModel.from_xml_string(f"""<mujoco><worldbody>
        <camera name="depth_front" pos="0 0 1.0" quat="1 0 0 0" fovy="60"/>
        <geom type="box" {box.replace('pos="0 0', 'pos="-0.15 0')}/>
        <site type="box" {box.replace('pos="0 0', 'pos="0.15 0')} rgba="1 1 1 0.3"/>
        </worldbody></mujoco>""")
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    cloud = DepthPointCloud(model, 256, ["front"])
    points = cloud(data, np.random.default_rng(0))
    cloud.close()
    above_table = points[points[:, 2] > 0.01]
    assert len(above_table) > 0 and np.all(
        np.abs(above_table[:, 0] + 0.15) < 0.04
    )  # the geom, never the site
