"""Why episodes fail: LeRobot's evaluation loop (the same processors and `select_action` as
`lerobot-eval`), rolled out here so the simulator can be read between steps.

A failed episode either never touches the task's object (the wrist went somewhere else) or touches it and
still fails (the hand did not press, grasp or hold). That separates the two halves of the action: the
wrist pose and the hand's joints (or its latent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

OUTCOMES = ("success", "never_touched", "touched_failed")


def episode_outcomes(
    model: Path,
    task: str,
    hand: str,
    regions: tuple[str, ...],
    n_points: int,
    episodes: int,
    seed: int,
    steps: int | None = None,
) -> list[str]:
    """One of `OUTCOMES` per seeded episode of the policy in `model` (a `pretrained_model` folder), each
    `steps` long (None: the task's episode length)."""
    import gymnasium as gym
    import torch
    from lerobot.envs.utils import preprocess_observation
    from lerobot.policies.factory import make_pre_post_processors

    import lerobot_policy_opfa  # noqa: F401  (registers the opfa policy and env types)
    from lerobot_opfa.envs.config import OpfaEnvConfig
    from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

    policy = OpfaPolicy.from_pretrained(model).eval()
    preprocessor, postprocessor = make_pre_post_processors(policy.config, pretrained_path=str(model))
    config = OpfaEnvConfig(
        task=task, hand=hand, regions=",".join(regions), obs_type="pointcloud",
        pointcloud_source="geometry", n_points=n_points, episode_length=steps,
    )  # fmt: skip
    env_preprocessor, _ = config.get_env_processors()
    kwargs = dict(config.gym_kwargs)
    max_steps = kwargs.pop("max_episode_steps")
    env = gym.make(config.gym_id, disable_env_checker=True, **kwargs).unwrapped
    outcomes = []
    for episode in range(episodes):
        observation, _ = env.reset(seed=seed + episode)
        torch.manual_seed(seed + episode)  # the diffusion noise too: a rerun draws the same episodes
        policy.reset()
        preprocessor.reset()
        touched = success = False
        for _ in range(max_steps):
            batch = preprocess_observation({k: np.asarray(v)[None] for k, v in observation.items()})
            batch["task"] = [env.task_description]
            with torch.inference_mode():
                action = policy.select_action(preprocessor(env_preprocessor(batch)))
            observation, _, success, _, _ = env.step(postprocessor(action)[0].numpy())
            touched = touched or env.task.touched(env.scene, env.data)
            if success:
                break
        outcomes.append("success" if success else "touched_failed" if touched else "never_touched")
    env.close()
    return outcomes
