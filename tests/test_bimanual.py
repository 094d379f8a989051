"""The two-armed scene: each arm a wrist carriage with its hand, a task that needs both hands (`lift_tray`,
a tray in two halves on a hinge) and its scripted expert, run in MuJoCo."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_opfa.envs.bimanual import SIDES, BimanualExpert, OpfaBimanualEnv, parse_hands
from lerobot_opfa.envs.scene import WRIST_JOINTS
from lerobot_opfa.hands import load_hand


def run_expert(env: OpfaBimanualEnv, seed: int, one_arm: bool = False) -> bool:
    """One seeded episode of the expert (with `one_arm`, the right arm stays home, its hand open)."""
    env.reset(seed=seed)
    expert = BimanualExpert(env, np.random.default_rng(seed))
    right = env.arm("right")
    home = np.concatenate([right.home, right.hand_open])
    for _ in range(env.task.episode_steps):
        action = expert.act()
        if one_arm:
            action[-len(home) :] = home
        if env.step(action)[2]:
            return True
    return False


@pytest.fixture(scope="module")
def env():
    env = OpfaBimanualEnv(hands="inspire+xhand", obs_type="state")
    yield env
    env.close()


def test_each_arm_holds_its_hand_and_the_entries_name_the_side(env):
    inspire, xhand = load_hand("inspire"), load_hand("xhand")
    assert env.state_names == [
        *(f"left_{n}" for n in (*WRIST_JOINTS, *inspire.joint_names)),
        *(f"right_{n}" for n in (*WRIST_JOINTS, *xhand.joint_names)),
    ]
    obs, _ = env.reset(seed=0)
    assert obs["agent_pos"].shape == env.action_space.shape == (12 + inspire.dof + xhand.dof,)
    left, right = obs["agent_pos"][:3], obs["agent_pos"][6 + inspire.dof : 9 + inspire.dof]
    assert left[1] > 0.1 and right[1] < -0.1, "the left wrist stands at +y, the right at -y"
    assert parse_hands("inspire, xhand") == parse_hands(["inspire", "xhand"]) == ["inspire", "xhand"]
    with pytest.raises(ValueError, match="two hands, left then right"):
        parse_hands("inspire")


def test_the_two_armed_expert_lifts_the_tray_level_and_one_arm_alone_never_does(env):
    assert sum(run_expert(env, seed) for seed in range(8)) >= 7
    assert not any(run_expert(env, seed, one_arm=True) for seed in range(4)), "one hand folds the tray"
    assert set(env.task.handles(env.placement)) == set(SIDES)
