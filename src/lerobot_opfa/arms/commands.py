"""`lerobot-opfa arms ...`: the built-in arms, and a check of an arm spec against its model."""

from __future__ import annotations

import argparse
from pathlib import Path

from lerobot_opfa.flags import positive_int


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    arms = subparsers.add_parser("arms", help="arm models: list, checks").add_subparsers(
        dest="arms_command", required=True
    )
    arms.add_parser("list", help="the built-in arms and whether their models are installed").set_defaults(
        func=_list
    )
    check = arms.add_parser(
        "check", help="check an arm spec against its model (FK vs MuJoCo, a hand's reach over the table)"
    )
    check.add_argument("arm", help="built-in name or path to an arm spec YAML")
    check.add_argument("--hand", default="umi", help="the hand mounted for the reach check (default umi)")
    check.add_argument(
        "--samples", type=positive_int, default=64, help="random joint values for the FK check"
    )
    check.add_argument("--png", type=Path, help="a picture of the arm, its hand and the regions it reaches")
    check.set_defaults(func=_check)


def _list(args: argparse.Namespace) -> int:
    from lerobot_opfa.arms.spec import ArmSpecError, builtin_arms, load_arm

    for name in builtin_arms():
        spec = load_arm(name)
        try:
            where = str(spec.model_path)
        except ArmSpecError as err:
            where = f"not installed: {str(err).rsplit(': ', 1)[-1]}"
        print(f"{name:8s} {len(spec.joints)} joints  flange {spec.flange:12s} {spec.description}  ({where})")
    return 0


def _check(args: argparse.Namespace) -> int:
    from lerobot_opfa.arms.check import FK_TOLERANCE, draw, fk_error_vs_mujoco, reach, sample_joints
    from lerobot_opfa.arms.pose import check_mount
    from lerobot_opfa.arms.spec import load_arm
    from lerobot_opfa.hands.registry import load_hand

    spec = load_arm(args.arm)
    chain = spec.chain()
    hand = load_hand(args.hand)
    position, rotation = fk_error_vs_mujoco(spec, chain, sample_joints(chain, args.samples))
    print(f"{spec.name}: {len(spec.joints)} joints, flange {spec.flange}, model {spec.model_path}")
    print(
        f"FK vs MuJoCo over {args.samples} random joint values: {position:.1e} m, {rotation:.1e} (rotation)"
    )
    check_mount(spec, chain, hand)
    print(f"mount: the {hand.name} clear of the arm's links at home")
    reached = reach(spec, chain, hand)
    missed = [name for name, ok in zip(reached.regions, reached.reached, strict=True) if not ok]
    print(
        f"reach with {hand.name}: {sum(reached.reached)}/{len(reached.regions)} table regions"
        + (f" (out of reach: {', '.join(missed)})" if missed else "")
    )
    if args.png:
        draw(spec, chain, hand, reached).savefig(args.png, dpi=110)
        print(f"wrote {args.png}")
    if max(position, rotation) > FK_TOLERANCE:
        raise ValueError(
            f"{spec.path}: FK differs from MuJoCo's by {max(position, rotation):.1e}: the chain read is not "
            "the model MuJoCo reads (check the model file and the flange)"
        )
    return 0
