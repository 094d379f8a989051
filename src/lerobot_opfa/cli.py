"""`lerobot-opfa`: the package's command line; each area adds its own subcommands."""

from __future__ import annotations

import argparse
import logging
import sys

from lerobot_opfa import demo, train
from lerobot_opfa.datasets import commands as dataset_commands
from lerobot_opfa.envs import commands as sim_commands
from lerobot_opfa.experiments import commands as experiment_commands
from lerobot_opfa.galr import commands as galr_commands
from lerobot_opfa.hands import commands as hands_commands
from lerobot_opfa.policy import commands as policy_commands


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lerobot-opfa", description=__doc__)
    subparsers = parser.add_subparsers(dest="command", required=True)
    hands_commands.add_commands(subparsers)
    sim_commands.add_commands(subparsers)
    dataset_commands.add_commands(subparsers)
    galr_commands.add_commands(subparsers)
    policy_commands.add_commands(subparsers)
    experiment_commands.add_commands(subparsers)
    train.add_command(subparsers)
    demo.add_command(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("lerobot_opfa").setLevel(logging.INFO)
    parser = build_parser()
    # `train` passes lerobot-train's flags through untouched; every other command takes only its own.
    args, unknown = parser.parse_known_args(argv)
    if getattr(args, "passthrough", False):
        args.lerobot_args = unknown
    elif unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    try:
        return args.func(args) or 0
    except (ValueError, FileNotFoundError, FileExistsError, KeyError, RuntimeError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
