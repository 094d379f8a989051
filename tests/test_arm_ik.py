"""Inverse kinematics of the arms example-robot-data ships (UR5, Franka Panda): the joints come back within
1 mm / 0.5 deg of reachable poses and within the joint limits, a chunk solves from the arm's current joints,
and a pose out of reach is answered, not refused."""

from __future__ import annotations

import sysconfig
from pathlib import Path

import pytest
import torch

from lerobot_opfa.arms.ik import MAX_STEP, ArmChain, pose_error, solve, solve_chunk

ROBOTS = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"
ARMS = {
    "ur5": ("ur_description/urdf/ur5_robot.urdf", "tool0", [0.3, -1.2, 1.4, -1.7, -1.5, 0.2]),
    "panda": ("panda_description/urdf/panda.urdf", "panda_link8", [0.1, -0.4, 0.0, -2.2, 0.0, 1.9, 0.8]),
}
"""Per arm: its URDF, its flange link and a working pose (the hand above a table in front of it)."""


def arm(name: str) -> ArmChain:
    path, flange, _ = ARMS[name]
    if not (ROBOTS / path).is_file():
        pytest.fail(f"example-robot-data's {name} not found at {ROBOTS / path}; install the [test] extra")
    return ArmChain.from_model(ROBOTS / path, flange)


def errors_mm_deg(
    chain: ArmChain, q: torch.Tensor, targets: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    error = pose_error(chain.flange_pose(q), targets)
    return 1000 * error[:, :3].norm(dim=-1), torch.rad2deg(error[:, 3:].norm(dim=-1))


@pytest.mark.parametrize("name", sorted(ARMS))
def test_reachable_poses_come_back_within_a_millimetre_and_half_a_degree_inside_the_limits(name):
    chain, generator = arm(name), torch.Generator().manual_seed(0)
    working = torch.tensor(ARMS[name][2], dtype=torch.float64)
    answer = (working + 0.3 * (2 * torch.rand(64, len(working), generator=generator) - 1)).clamp(
        chain.lower, chain.upper
    )
    seed = answer + 0.05 * torch.randn(answer.shape, generator=generator, dtype=torch.float64)
    q, _ = solve(chain, chain.flange_pose(answer), seed)
    mm, deg = errors_mm_deg(chain, q, chain.flange_pose(answer))
    assert mm.quantile(0.95) <= 1.0 and deg.quantile(0.95) <= 0.5, (mm.max(), deg.max())
    assert ((q >= chain.lower) & (q <= chain.upper)).all()


@pytest.mark.parametrize("name", sorted(ARMS))
def test_a_chunk_of_poses_is_solved_from_the_joints_the_arm_holds(name):
    """Eight poses of a trajectory 0.02 rad a step in every joint, as a policy's chunk asks them."""
    chain = arm(name)
    current = torch.tensor(ARMS[name][2], dtype=torch.float64)
    direction = torch.tensor([1.0, -1.0] * 4, dtype=torch.float64)[: len(current)]
    trajectory = current + 0.02 * torch.arange(1, 9, dtype=torch.float64)[:, None] * direction
    targets = chain.flange_pose(trajectory)
    q, _ = solve_chunk(chain, targets, current)
    mm, deg = errors_mm_deg(chain, q, targets)
    assert q.shape == trajectory.shape and mm.max() <= 1.0 and deg.max() <= 0.5, (mm, deg)


def test_a_pose_out_of_reach_is_answered_with_the_joints_nearest_it_inside_the_limits():
    chain = arm("ur5")
    current = torch.tensor(ARMS["ur5"][2], dtype=torch.float64)
    far = chain.flange_pose(current[None]).clone()
    far[:, :3, 3] += torch.tensor([2.0, 0.0, 0.0], dtype=torch.float64)  # 2 m beyond the arm's reach
    q, error = solve(chain, far, current[None])
    assert ((q >= chain.lower) & (q <= chain.upper)).all() and torch.isfinite(q).all()
    assert error[:, :3].norm() > 1.0  # reported, for the caller to count
    assert (q - current).abs().max() <= 8 * MAX_STEP + 1e-9  # no joint moved more than MAX_STEP an iteration


def test_a_flange_that_is_not_a_link_is_one_line_naming_it():
    with pytest.raises(ValueError, match=r"flange link 'tool9' is not a link of the model \(.*tool0"):
        ArmChain.from_model(ROBOTS / ARMS["ur5"][0], "tool9")
