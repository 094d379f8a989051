"""`lerobot-opfa demo` (what `make demo` runs): the pipeline end to end on a small built-in default.

So far: every built-in hand, its FK checked against MuJoCo and its open and grasp clouds drawn; then the
default GaLR checkpoint round-trips held-out states of every hand (joints -> cloud -> z -> joints).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from tqdm import tqdm

from lerobot_opfa.galr.evaluate import evaluate_hand, held_out_joints, plot_reconstructions
from lerobot_opfa.galr.model import Galr
from lerobot_opfa.hands.plot import plot_clouds
from lerobot_opfa.hands.registry import builtin_hands, load_hand
from lerobot_opfa.hands.validate import fk_error_vs_mujoco
from lerobot_opfa.resources import default_galr_checkpoint


def add_command(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("demo", help="run the pipeline end to end on a small default")
    parser.add_argument("--output-dir", type=Path, default=Path("outputs/demo"))
    parser.add_argument("--n-points", type=int, default=1024)
    parser.add_argument(
        "--galr", default=str(default_galr_checkpoint()), help="GaLR checkpoint (dir or repo)"
    )
    parser.add_argument(
        "--states", type=int, default=64, help="held-out states per hand for the GaLR round trip"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    galr = Galr.from_pretrained(args.galr).eval()
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
        galr_metrics = evaluate_hand(galr, name, held_out_joints(galr, name, args.states, seed=0))
        rows.append((name, hand.dof, position_error, galr_metrics, png))
    reconstructions = plot_reconstructions(
        galr, list(builtin_hands()), args.output_dir / "galr_reconstructions.png"
    )

    header = f"{'hand':<16}{'dof':>4}{'FK vs MuJoCo (m)':>18}{'GaLR RMSE (deg)':>17}{'fingertip (mm)':>16}"
    print(f"\n{header}  picture")
    for name, dof, error, metrics, png in rows:
        rmse, tip = metrics["joint_rmse_deg"], metrics["fingertip_error_mm"]
        print(f"{name:<16}{dof:>4}{error:>18.1e}{rmse:>17.2f}{tip:>16.2f}  {png}")
    print(f"GaLR {args.galr}: original vs decoded clouds in {reconstructions}")
    return 0
