"""`lerobot-opfa policy ...`: commands on trained policy checkpoints."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    policy = subparsers.add_parser("policy", help="trained policy checkpoints").add_subparsers(
        dest="policy_command", required=True
    )
    convert = policy.add_parser(
        "convert-io", help="give a stock policy trained on a latent dataset a joint-space interface"
    )
    convert.add_argument("--policy", type=Path, required=True, help="checkpoint folder (pretrained_model)")
    convert.add_argument(
        "--galr", required=True, help="the GaLR the latent dataset was made with (name, folder, repo)"
    )
    convert.add_argument("--output", type=Path, required=True)
    convert.add_argument("--hand", help="hand of observations without an embodiment id (default: inferred)")
    convert.set_defaults(func=_convert)


def _convert(args: argparse.Namespace) -> None:
    from lerobot_opfa.policy.stock_io import convert_policy_io

    convert_policy_io(args.policy, args.galr, args.output, args.hand)
    print(f"wrote {args.output}: the policy of {args.policy} with a joint-space interface")
