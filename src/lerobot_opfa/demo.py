"""`lerobot-opfa demo` (what `make demo` runs): the pipeline end to end on a small built-in default.

So far: every built-in hand, its FK checked against MuJoCo, and its open and grasp clouds drawn.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from tqdm import tqdm

from lerobot_opfa.hands.plot import plot_clouds
from lerobot_opfa.hands.registry import builtin_hands, load_hand
from lerobot_opfa.hands.validate import fk_error_vs_mujoco


def add_command(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("demo", help="run the pipeline end to end on a small default")
    parser.add_argument("--output-dir", type=Path, default=Path("outputs/demo"))
    parser.add_argument("--n-points", type=int, default=1024)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    rows = []
    for name in tqdm(list(builtin_hands()), desc="hands", unit="hand"):
        hand = load_hand(name)
        q = hand.sample_joints(32, torch.Generator().manual_seed(0))
        position_error, _ = fk_error_vs_mujoco(hand, q)
        poses = torch.stack([hand.pose("open"), hand.pose("grasp")])
        cloud = hand.point_cloud(poses, args.n_points)
        clouds = {
            p: (cloud.points[i].numpy(), cloud.labels[i].numpy()) for i, p in enumerate(("open", "grasp"))
        }
        png = plot_clouds(clouds, args.output_dir / f"hand_{name}.png", title=hand.spec.description)
        rows.append((name, hand.dof, len(hand.chain_joint_names), position_error, png))
    print(f"\n{'hand':<16}{'dof':>4}{'joints':>8}{'FK vs MuJoCo (m)':>18}  picture")
    for name, dof, joints, error, png in rows:
        print(f"{name:<16}{dof:>4}{joints:>8}{error:>18.1e}  {png}")
    return 0
