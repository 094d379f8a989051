"""Checks that an arm spec and its model describe an arm that can carry a hand over the benchmark's table:
its FK agrees with MuJoCo's own kinematics, and the mounted hand reaches each table region pointing down
(`lerobot-opfa arms check`, with a picture of the arm and its hand at home and the regions it reaches)."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from lerobot_opfa.arms.ik import ArmChain, solve
from lerobot_opfa.arms.pose import wrist_in_tool
from lerobot_opfa.arms.spec import ArmSpec, transform
from lerobot_opfa.envs.regions import REGIONS
from lerobot_opfa.envs.scene import TABLE_HALF
from lerobot_opfa.hands.model import HandModel

FK_TOLERANCE = 1e-5
"""m, and rotation-matrix entries: FK that differs from MuJoCo's by more reads another model."""
REACH_HEIGHT = 0.10
"""m above the table: where the hand's tool frame must get to over each region, approach axis down."""
REACH_TOLERANCE = (1e-3, math.radians(0.5))
"""m and rad: a region whose pose IK leaves farther off than this is out of reach."""
REACH_ITERATIONS = 200
"""From home to a far region, 60 iterations left the Panda's elbow short of one region that 150 reach."""


def mujoco_arm(spec: ArmSpec) -> mujoco.MjModel:
    """The arm's model compiled by MuJoCo, its links kept as bodies. A URDF is read without its meshes (its
    kinematics need none, and `package://` paths are not MuJoCo's)."""
    path = spec.model_path
    if path.suffix != ".urdf":
        return mujoco.MjModel.from_xml_path(str(path))
    root = ET.parse(path).getroot()
    for link in root.iter("link"):
        for element in [*link.findall("visual"), *link.findall("collision")]:
            link.remove(element)
    ET.SubElement(ET.SubElement(root, "mujoco"), "compiler", fusestatic="false", discardvisual="true")
    return mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))


def sample_joints(chain: ArmChain, n: int, seed: int = 0) -> torch.Tensor:
    """(n, dof) joints drawn within the limits (at most half a turn either way of zero)."""
    lower, upper = chain.lower.clamp(min=-math.pi), chain.upper.clamp(max=math.pi)
    unit = torch.rand(n, len(lower), generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    return lower + unit * (upper - lower)


def fk_error_vs_mujoco(spec: ArmSpec, chain: ArmChain, q: torch.Tensor) -> tuple[float, float]:
    """Largest flange position error (m) and rotation-matrix entry error between our FK and MuJoCo's."""
    model = mujoco_arm(spec)
    data = mujoco.MjData(model)
    address = [model.jnt_qposadr[model.joint(name).id] for name in spec.joints]
    flange = model.body(spec.flange).id
    ours = chain.flange_pose(q).numpy()
    position, rotation = 0.0, 0.0
    for values, pose in zip(q.numpy(), ours, strict=True):
        data.qpos[address] = values
        mujoco.mj_kinematics(model, data)
        position = max(position, float(np.abs(data.xpos[flange] - pose[:3, 3]).max()))
        rotation = max(rotation, float(np.abs(data.xmat[flange].reshape(3, 3) - pose[:3, :3]).max()))
    return position, rotation


@dataclass
class Reach:
    regions: list[str]
    reached: list[bool]
    joints: torch.Tensor
    """(regions, dof): the joints IK found for each region."""


def reach(spec: ArmSpec, chain: ArmChain, hand: HandModel) -> Reach:
    """Whether the mounted hand's tool frame gets to `REACH_HEIGHT` over each region's centre, approach axis
    down, by IK from home."""
    names = list(REGIONS)
    centres = [(np.mean(REGIONS[n].x), np.mean(REGIONS[n].y)) for n in names]
    down = torch.stack([transform([x, y, REACH_HEIGHT], [math.pi, 0.0, 0.0]) for x, y in centres])
    wrist = down @ wrist_in_tool(hand)
    targets = spec.flange_target(wrist)
    home = torch.tensor(spec.home, dtype=torch.float64).expand(len(names), -1)
    q, error = solve(chain, targets, home, REACH_ITERATIONS)
    ok = (error[:, :3].norm(dim=-1) <= REACH_TOLERANCE[0]) & (error[:, 3:].norm(dim=-1) <= REACH_TOLERANCE[1])
    return Reach(names, ok.tolist(), q)


def draw(spec: ArmSpec, chain: ArmChain, hand: HandModel, reached: Reach):
    """Side and top views: the arm's links at home and the hand on its flange; the table and its regions,
    green where the hand reaches them."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    home = torch.tensor([spec.home], dtype=torch.float64)
    frames = chain.chain.forward_kinematics(home, end_only=False)
    joints = np.stack([(spec.base @ frames[name].get_matrix()[0])[:3, 3].numpy() for name in frames])
    wrist = spec.wrist_pose(chain, home)[0]
    cloud = hand.point_cloud(hand.pose("open")[None].to(hand.dtype), 512).points[0].double()
    cloud = (cloud @ wrist[:3, :3].T + wrist[:3, 3]).numpy()
    figure = Figure(figsize=(10, 4.5))
    side, top = figure.subplots(1, 2)
    for axis, (i, j), label in ((side, (0, 2), "z"), (top, (0, 1), "y")):
        axis.plot(joints[:, i], joints[:, j], "o-", color="0.3", label=f"{spec.name} at home")
        axis.scatter(cloud[:, i], cloud[:, j], s=2, color="tab:orange", label=hand.name)
        axis.set_xlabel("x (m)")
        axis.set_ylabel(f"{label} (m)")
        axis.set_aspect("equal")
    side.plot([-TABLE_HALF[0], TABLE_HALF[0]], [0, 0], color="saddlebrown", lw=3, label="table top")
    corner, size = (-TABLE_HALF[0], -TABLE_HALF[1]), (2 * TABLE_HALF[0], 2 * TABLE_HALF[1])
    top.add_patch(Rectangle(corner, *size, color="wheat", zorder=0))
    for name, ok in zip(reached.regions, reached.reached, strict=True):
        x, y = np.mean(REGIONS[name].x), np.mean(REGIONS[name].y)
        top.plot(x, y, "s", color="tab:green" if ok else "tab:red", ms=9)
    side.set_title("side")
    top.set_title(f"top: regions reached {sum(reached.reached)}/{len(reached.regions)} (green)")
    side.legend(loc="upper right", fontsize=7)
    figure.tight_layout()
    return figure
