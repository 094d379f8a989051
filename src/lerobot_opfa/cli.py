"""`lerobot-opfa`: the package's command line; each area adds its own subcommands."""

from __future__ import annotations

import argparse
import logging
import signal
import sys

from draccus.utils import DecodingError

from lerobot_opfa import demo, train
from lerobot_opfa.arms import commands as arm_commands
from lerobot_opfa.datasets import commands as dataset_commands
from lerobot_opfa.envs import choose_headless_gl
from lerobot_opfa.envs import commands as sim_commands
from lerobot_opfa.experiments import commands as experiment_commands
from lerobot_opfa.flags import OneLineParser
from lerobot_opfa.galr import commands as galr_commands
from lerobot_opfa.hands import commands as hands_commands
from lerobot_opfa.policy import commands as policy_commands


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="lerobot-opfa", description=__doc__)
    subparsers = parser.add_subparsers(dest="command", required=True)
    hands_commands.add_commands(subparsers)
    arm_commands.add_commands(subparsers)
    sim_commands.add_commands(subparsers)
    dataset_commands.add_commands(subparsers)
    galr_commands.add_commands(subparsers)
    policy_commands.add_commands(subparsers)
    experiment_commands.add_commands(subparsers)
    train.add_command(subparsers)
    demo.add_command(subparsers)
    return parser


class _ShortVideoBackendWarning(logging.Filter):
    """LeRobot logs torchcodec's whole loading traceback (about 100 lines) when FFmpeg's libraries are
    missing, then falls back to pyav by itself, and does so each time it picks a backend: one line, once,
    says as much."""

    shown = False

    def filter(self, record: logging.LogRecord) -> bool:
        if "Falling back to 'pyav'" not in str(record.msg):
            return True
        record.msg, record.args = "torchcodec cannot be loaded here; LeRobot decodes videos with pyav", ()
        first, self.shown = not self.shown, True
        return first


def main(argv: list[str] | None = None) -> int:
    choose_headless_gl()
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("lerobot_opfa").setLevel(logging.INFO)
    logging.getLogger("lerobot.utils.import_utils").addFilter(_ShortVideoBackendWarning())
    signal.signal(signal.SIGTERM, _exit_on_sigterm)  # so that writers clean up as on Ctrl-C
    parser = build_parser()
    # `train` passes lerobot-train's flags through untouched; every other command takes only its own.
    args, unknown = parser.parse_known_args(argv)
    if getattr(args, "passthrough", False):
        args.lerobot_args = unknown
    elif unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    try:
        return args.func(args) or 0
    except (ValueError, DecodingError, FileNotFoundError, FileExistsError, KeyError, RuntimeError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


def _exit_on_sigterm(signum, frame):
    raise KeyboardInterrupt


if __name__ == "__main__":
    sys.exit(main())
