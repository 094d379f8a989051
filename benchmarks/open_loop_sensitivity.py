"""How a trained policy's predicted wrist follows what it sees, open loop, on its own demos' frames.

    HF_HUB_OFFLINE=1 .venv/bin/python benchmarks/open_loop_sensitivity.py CHECKPOINT DATASET [--frames 60]

For evenly spaced frames of DATASET (with the frame before each, for the observation history): the
predicted wrist x (the last executed action of the chunk, a fixed noise) when the wrist state alone, the
point cloud alone, or both move by 1 cm in x, in cm per cm. A policy that moves with the scene gives 1 for
both; below 1 it pulls toward the demos' mean. Prints one JSON line (docs/results.md, LEAP pull_drawer).
"""

from __future__ import annotations

import argparse
import json

import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors
from lerobot.utils.constants import OBS_STATE

from lerobot_opfa.features import OBS_POINTCLOUD
from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

SHIFT = 0.01  # m


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("dataset")
    parser.add_argument("--frames", type=int, default=60)
    args = parser.parse_args()

    torch.manual_seed(0)
    policy = OpfaPolicy.from_pretrained(args.checkpoint).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=args.checkpoint)
    columns = LeRobotDataset("local/demos", root=args.dataset).hf_dataset.with_format("torch")[:]
    states, clouds, episodes = columns[OBS_STATE], columns[OBS_POINTCLOUD], columns["episode_index"]
    rows = [
        i
        for i in torch.linspace(1, len(states) - 1, args.frames).long().tolist()
        if episodes[i] == episodes[i - 1]
    ]
    state = torch.stack([states[i - 1 : i + 1] for i in rows])
    cloud = torch.stack([clouds[i - 1 : i + 1] for i in rows])
    noise = torch.randn(len(rows), policy.config.horizon, policy.config.action_width)

    def wrist_x(state: torch.Tensor, cloud: torch.Tensor) -> torch.Tensor:
        policy.reset()
        with torch.no_grad():
            chunk = policy.predict_action_chunk(pre({OBS_STATE: state, OBS_POINTCLOUD: cloud}), noise=noise)
        return post(chunk[:, -1])[:, 0]

    moved_state = state.clone()
    moved_state[..., 0] += SHIFT
    moved_cloud = cloud.clone().view(len(rows), 2, -1, 3)
    moved_cloud[..., 0] += SHIFT
    moved_cloud = moved_cloud.view(len(rows), 2, -1)
    base = wrist_x(state, cloud)

    def follows(state: torch.Tensor, cloud: torch.Tensor) -> float:
        return round(float(((wrist_x(state, cloud) - base) / SHIFT).mean()), 3)

    print(json.dumps({
        "checkpoint": args.checkpoint, "frames": len(rows), "wrist_state": follows(moved_state, cloud),
        "cloud": follows(state, moved_cloud), "both": follows(moved_state, moved_cloud),
    }))  # fmt: skip


if __name__ == "__main__":
    main()
