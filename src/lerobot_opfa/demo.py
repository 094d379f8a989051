"""`lerobot-opfa demo` (what `make demo` runs): the whole pipeline on a small built-in default.

1. Hands: every built-in hand's FK checked against MuJoCo, its open and grasp clouds drawn, and the long
   GaLR checkpoint's round trip (joints -> cloud -> z -> joints) on held-out states.
2. Policy: scripted demos of three embodiments (a gripper and two dexterous hands) on one task in one region
   of the table, merged into one dataset, one OPFA policy trained on all of them with `lerobot-opfa train`
   (LeRobot's training on the dataset held in memory), and every embodiment evaluated with `lerobot-eval`
   where its demos are, beside the control (the same policy untrained); a success table, `success.json`
   and a plot at the end.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from tqdm import tqdm

from lerobot_opfa.experiments.scales import DEMO_SCALE
from lerobot_opfa.flags import positive_int


def add_command(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("demo", help="run the pipeline end to end on a small default")
    parser.add_argument("--output-dir", type=Path, default=Path("outputs/demo"))
    parser.add_argument("--n-points", type=positive_int, default=1024, help="points of the hand clouds drawn")
    parser.add_argument("--galr", default="long", help="GaLR checkpoint: packaged name, folder or Hub repo")
    parser.add_argument(
        "--states", type=positive_int, default=64, help="held-out states per hand for the GaLR round trip"
    )
    parser.add_argument("--task", default="press_button")
    parser.add_argument("--hands", default="umi,inspire,xhand", help="the embodiments co-trained")
    parser.add_argument("--region", default="mid_center", help="where the demos are and the policy is tested")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    hands_table(args)
    policy_table(args)
    return 0


def hands_table(args: argparse.Namespace) -> None:
    import torch

    from lerobot_opfa.galr import checkpoints
    from lerobot_opfa.galr.evaluate import evaluate_hand, held_out_joints, plot_reconstructions
    from lerobot_opfa.galr.frozen import galr_hand_refs
    from lerobot_opfa.hands.plot import plot_clouds
    from lerobot_opfa.hands.registry import builtin_hands, load_hand
    from lerobot_opfa.hands.validate import fk_error_vs_mujoco

    galr = checkpoints.load(args.galr)
    trained_on = galr_hand_refs(galr)
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
        galr_metrics = (
            evaluate_hand(galr, name, held_out_joints(galr, name, args.states, seed=0))
            if name in trained_on
            else None
        )
        rows.append((name, hand.dof, position_error, galr_metrics, png))
    reconstructions = plot_reconstructions(galr, trained_on, args.output_dir / "galr_reconstructions.png")

    header = f"{'hand':<16}{'dof':>4}{'FK vs MuJoCo (m)':>18}{'GaLR RMSE (deg)':>17}{'fingertip (mm)':>16}"
    print(f"\n{header}  picture")
    for name, dof, error, metrics, png in rows:
        if metrics is None:
            print(f"{name:<16}{dof:>4}{error:>18.1e}{'not in this GaLR':>33}  {png}")
            continue
        rmse, tip = metrics["joint_rmse_deg"], metrics["fingertip_error_mm"]
        print(f"{name:<16}{dof:>4}{error:>18.1e}{rmse:>17.2f}{tip:>16.2f}  {png}")
    print(f"GaLR {args.galr}: original vs decoded clouds in {reconstructions}\n")


def policy_table(args: argparse.Namespace) -> None:
    """Demos -> merge -> train (OPFA) -> lerobot-eval per embodiment, in the demos' region."""
    from lerobot_opfa.envs.regions import parse_regions
    from lerobot_opfa.experiments.jobs import Demos, Workspace
    from lerobot_opfa.experiments.protocols import TRANSFER, co_training
    from lerobot_opfa.experiments.report import markdown_table, plot, summarize

    hands = [h.strip() for h in args.hands.split(",") if h.strip()]
    region = tuple(parse_regions(args.region))
    demos = [Demos(args.task, h, region, DEMO_SCALE.demos) for h in hands]
    tests = [(args.task, region)] * len(hands)  # where the demos are: transfer and ceiling cells coincide
    conditions = ("opfa", "untrained")  # beside OPFA, the control: the same policy untrained
    cells = [c for c in co_training(args.task, demos, tests, conditions, seed=0) if c.kind == TRANSFER]
    workspace = Workspace(args.output_dir / "pipeline", DEMO_SCALE, args.galr)
    rows = []
    progress = "cells evaluated (hand x policy; demos, merge and training come first)"
    with tqdm(total=len(cells), desc=progress) as bar:
        for cell in cells:
            rows.append({"group": cell.group, **workspace.evaluate(cell.evaluation)})
            bar.update()
    rows = summarize(rows)
    success = {}
    for r in rows:
        success.setdefault(r["condition"], {})[r["hand"]] = {
            "successes": sum(r["successes"]),
            "episodes": r["episodes"],
        }
    (args.output_dir / "success.json").write_text(json.dumps(success, indent=2))
    png = plot(rows, args.output_dir / "success.png", f"OPFA co-trained on {', '.join(hands)}")
    print(
        f"One OPFA policy, co-trained on {DEMO_SCALE.demos} scripted demos of each hand in {args.region} "
        f"({DEMO_SCALE.epochs:g} epochs); {DEMO_SCALE.eval_episodes} evaluation episodes per hand there, "
        "beside the control, the same policy untrained (what the task gives a policy that learnt nothing):\n"
    )
    print(markdown_table(rows))
    print(f"plot: {png}; videos: {workspace.root / 'videos'}; policy: {workspace.root / 'train'}")
