"""Why episodes fail: LeRobot's evaluation loop (the same processors and `select_action` as
`lerobot-eval`), rolled out here so the simulator can be read between steps.

A failed episode either never touches the task's object (the wrist went somewhere else) or touches it and
still fails (the hand did not press, grasp or hold). That separates the two halves of the action: the
wrist pose and the hand's joints (or its latent). Whether the wrist goes where the object is at all
(`object_following`) tells a policy that reads the object from its camera from one that replays the
demonstrations' average path."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lerobot_opfa.envs import DEFAULT_FPS

if TYPE_CHECKING:
    from lerobot_opfa.envs.config import OpfaEnvConfig

OUTCOMES = ("success", "never_touched", "touched_failed")


def _loaded(model: Path, config: OpfaEnvConfig) -> tuple:
    """The policy in `model` (a `pretrained_model` folder: `opfa`, or a stock policy given joint-space
    processors by `policy convert-io`, its class from its config) with its processors, as `lerobot-eval`
    loads them, and the env `config` describes, with a function that batches its observations for them."""
    import gymnasium as gym
    from lerobot.envs.utils import preprocess_observation
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    import lerobot_policy_opfa  # noqa: F401  (registers the opfa policy and env types)
    from lerobot_opfa.policy.deploy import checkpoint_config

    policy = get_policy_class(checkpoint_config(Path(model)).type).from_pretrained(model).eval()
    preprocessor, postprocessor = make_pre_post_processors(policy.config, pretrained_path=str(model))
    env_preprocessor, _ = config.get_env_processors()
    kwargs = dict(config.gym_kwargs)
    max_steps = kwargs.pop("max_episode_steps")
    env = gym.make(config.gym_id, disable_env_checker=True, **kwargs).unwrapped

    def batched(value):  # `pixels` is a dict of cameras
        return {k: v[None] for k, v in value.items()} if isinstance(value, dict) else np.asarray(value)[None]

    def policy_input(observation: dict) -> dict:
        batch = preprocess_observation({k: batched(v) for k, v in observation.items()})
        batch["task"] = [env.task_description]
        return preprocessor(env_preprocessor(batch))

    return policy, policy_input, postprocessor, preprocessor, env, max_steps


def rollouts(model: Path, config: OpfaEnvConfig, episodes: int, seed: int) -> Iterator[tuple]:
    """(env at the episode's end, success, touched) for each of `episodes` seeded episodes of the policy in
    `model` (a `pretrained_model` folder) in the env `config` describes."""
    import torch

    policy, policy_input, postprocessor, preprocessor, env, max_steps = _loaded(model, config)
    try:
        for episode in range(episodes):
            observation, _ = env.reset(seed=seed + episode)
            torch.manual_seed(seed + episode)  # the diffusion noise too: a rerun draws the same episodes
            policy.reset()
            preprocessor.reset()
            touched = success = False
            for _ in range(max_steps):
                with torch.inference_mode():
                    action = policy.select_action(policy_input(observation))
                observation, _, success, _, _ = env.step(postprocessor(action)[0].numpy())
                touched = touched or env.task.touched(env.scene, env.data)
                if success:
                    break
            yield env, success, touched
    finally:
        env.close()


def episode_outcomes(
    model: Path,
    task: str,
    hand: str,
    regions: tuple[str, ...],
    n_points: int,
    episodes: int,
    seed: int,
    steps: int | None = None,
    arm: str | None = None,
    fps: int = DEFAULT_FPS,
) -> list[str]:
    """One of `OUTCOMES` per seeded episode of a point-cloud policy, each `steps` long (None: the task's
    episode length), the hand on `arm` (None: the floating wrist) at `fps`."""
    from lerobot_opfa.envs.config import OpfaEnvConfig

    config = OpfaEnvConfig(
        task=task, hand=hand, regions=",".join(regions), obs_type="pointcloud",
        pointcloud_source="geometry", n_points=n_points, episode_length=steps, arm=arm, fps=fps,
    )  # fmt: skip
    return [outcome(success, touched) for _, success, touched in rollouts(model, config, episodes, seed)]


def outcome(success: bool, touched: bool) -> str:
    """One of `OUTCOMES`."""
    return "success" if success else "touched_failed" if touched else "never_touched"


def object_following(model: Path, config: OpfaEnvConfig, episodes: int, seed: int) -> dict:
    """How far the wrist follows the object: the least-squares slope of the wrist's (x, y) at each episode's
    end on where reset placed the object, averaged over the two axes. About 1: the policy goes where the
    object is; about 0: it goes to the same place whatever its cameras show. With the same episodes'
    `outcomes` (`OUTCOMES` counted): whether a failure ever touched the object."""
    placed, reached, outcomes = [], [], dict.fromkeys(OUTCOMES, 0)
    for env, success, touched in rollouts(model, config, episodes, seed):
        placed.append(env.placement.xy.copy())
        reached.append(env.data.qpos[env.scene.wrist_qpos][:2].copy())
        outcomes[outcome(success, touched)] += 1
    slopes, _ = _lines(np.array(placed), np.array(reached))
    return {
        "follows_object": round(float(np.mean(slopes)), 2),
        "following_episodes": episodes,
        "outcomes": outcomes,
    }


def _lines(placed: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per axis (x, y): the least-squares slope of `values` on where reset `placed` the object, and the
    standard deviation of the residuals about that line."""
    slopes, scatters = [], []
    for axis in range(2):
        slope, intercept = np.polyfit(placed[:, axis], values[:, axis], 1)
        slopes.append(slope)
        scatters.append((values[:, axis] - (slope * placed[:, axis] + intercept)).std())
    return np.array(slopes), np.array(scatters)


def image_goal_scatter(model: Path, config: OpfaEnvConfig, episodes: int, seed: int) -> dict:
    """How precisely an RGB policy's `image_goal` head places the object from the first picture: over
    `episodes` resets, the scatter of its wrist estimate's x and y about their least-squares lines on where
    reset placed the object, over those lines' slopes: in cm of the object's place. What the features know,
    beside what the policy does with them (`object_following`)."""
    import torch

    policy, policy_input, _, _, env, _ = _loaded(model, config)
    placed, estimated = [], []
    try:
        for episode in range(episodes):
            batch = policy_input(env.reset(seed=seed + episode)[0])
            with torch.inference_mode():
                features = policy.encode_images({k: batch[k][:, None] for k in policy.image_keys})
                estimated.append(policy.image_goal(features[:, 0])[0, :2].numpy())
            placed.append(env.placement.xy.copy())
    finally:
        env.close()
    slopes, scatters = _lines(np.array(placed), np.array(estimated))
    return {
        "goal_scatter_cm": [round(float(c), 2) for c in 100 * scatters / abs(slopes)],
        "goal_episodes": episodes,
    }
