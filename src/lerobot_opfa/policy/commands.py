"""`lerobot-opfa policy ...`: commands on trained policy checkpoints."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    policy = subparsers.add_parser("policy", help="trained policy checkpoints").add_subparsers(
        dest="policy_command", required=True
    )
    dataset = policy.add_parser(
        "latent-dataset",
        help="a dataset's copy with state/action in the policy space (body + z), for a stock policy",
    )
    dataset.add_argument("--input", type=Path, required=True, help="a dataset opfa trains on")
    dataset.add_argument("--output", type=Path, required=True)
    dataset.add_argument("--galr", help="GaLR checkpoint (default: the merge's, else the packaged default)")
    dataset.add_argument("--drop", default="", help="comma-separated features to leave out")
    dataset.add_argument(
        "--joint-map", type=Path, help="how a robot's dataset holds its hand (as --policy.joint_map)"
    )
    dataset.add_argument("--overwrite", action="store_true")
    dataset.set_defaults(func=_dataset)
    convert = policy.add_parser(
        "convert-io", help="give a stock policy trained on a latent dataset a joint-space interface"
    )
    convert.add_argument("--policy", type=Path, required=True, help="checkpoint folder (pretrained_model)")
    convert.add_argument(
        "--dataset",
        type=Path,
        help="the policy-space dataset it was trained on (default: its train_config's)",
    )
    convert.add_argument("--output", type=Path, required=True)
    convert.add_argument("--hand", help="the robot of frames that do not say, for a policy of several")
    convert.set_defaults(func=_convert)
    pin = policy.add_parser(
        "for-robot", help="a copy of a checkpoint of several robots that drives one (for lerobot-rollout)"
    )
    pin.add_argument("--policy", type=Path, required=True, help="checkpoint folder (pretrained_model)")
    pin.add_argument(
        "--hand",
        required=True,
        help="the robot's hand, one the policy was trained on (two arms: inspire+xhand)",
    )
    pin.add_argument(
        "--robot-type",
        help="a robot_type that names other hands, of a robot that carries --hand's (refused otherwise)",
    )
    pin.add_argument("--output", type=Path, required=True)
    pin.set_defaults(func=_pin)


def _dataset(args: argparse.Namespace) -> None:
    from lerobot_opfa.policy.stock import latent_dataset

    drop = tuple(name for name in args.drop.split(",") if name)
    out = latent_dataset(args.input, args.output, args.galr, drop, args.overwrite, args.joint_map)
    print(f"wrote {out}: the frames of {args.input} with state and action in the policy space")


def _convert(args: argparse.Namespace) -> None:
    from lerobot_opfa.policy.stock import convert_checkpoint

    out, width = convert_checkpoint(args.policy, args.output, args.dataset, args.hand)
    print(
        f"wrote {out}: the policy of {args.policy} with a joint-space interface; lerobot-eval with "
        f"--env.type=opfa reads its action width ({width}: body + z) from it"
    )


def _pin(args: argparse.Namespace) -> None:
    from lerobot_opfa.policy.deploy import pin_robot

    out = pin_robot(args.policy, args.hand, args.output, args.robot_type)
    also = f", robot_type '{args.robot_type}' too" if args.robot_type else ""
    print(f"wrote {out}: the policy of {args.policy}, reading every frame as hand '{args.hand}'s robot{also}")
