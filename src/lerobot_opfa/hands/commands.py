"""`lerobot-opfa hands ...`: list the registered hands, draw their clouds, check a spec."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from lerobot_opfa.flags import positive_int
from lerobot_opfa.hands.registry import builtin_hands, hand_models_dir, load_spec


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    hands = subparsers.add_parser("hands", help="hand models: list, clouds, pictures, checks").add_subparsers(
        dest="hands_command", required=True
    )
    listing = hands.add_parser("list", help="the built-in hands")
    listing.add_argument("--json", action="store_true", help="print JSON instead of a table")
    listing.add_argument(
        "--joints", action="store_true", help="each hand's joints too: units and limits (loads the models)"
    )
    listing.set_defaults(func=_list)

    hands.add_parser("joints", help="the universal joint table").set_defaults(func=_joints)

    cloud = hands.add_parser("cloud", help="point clouds of random reachable states, saved as .npz")
    cloud.add_argument("hand", help="built-in name or path to a spec.yaml")
    cloud.add_argument("--n-points", type=positive_int, default=1024)
    cloud.add_argument("--batch", type=positive_int, default=16)
    cloud.add_argument("--seed", type=int, default=0)
    cloud.add_argument("--out", type=Path, required=True)
    cloud.set_defaults(func=_cloud)

    show = hands.add_parser("show", help="a picture of the hand's cloud, coloured by finger")
    show.add_argument("hand")
    show.add_argument("--out", type=Path, required=True)
    show.add_argument("--joints", choices=["open", "grasp", "random"], default="open")
    show.add_argument("--n-points", type=positive_int, default=2048)
    show.add_argument("--seed", type=int, default=0)
    show.set_defaults(func=_show)

    check = hands.add_parser("check", help="check a spec against its model (FK vs MuJoCo, couplings, poses)")
    check.add_argument("hand")
    check.add_argument("--png")
    check.add_argument(
        "--suggest", action="store_true", help="print the base, side and signs measured, as YAML"
    )
    check.set_defaults(func=_check)


def _check(args: argparse.Namespace) -> int:
    from lerobot_opfa.hands import validate

    flags = (["--png", args.png] if args.png else []) + (["--suggest"] if args.suggest else [])
    return validate.main([args.hand, *flags])


def _joints(args: argparse.Namespace) -> int:
    from lerobot_opfa.hands.universal import universal_table_markdown

    print(universal_table_markdown())
    return 0


def _list(args: argparse.Namespace) -> int:
    """From the specs alone (a spec names every movable joint: actuated or coupled), without the models."""
    rows = []
    for name in builtin_hands():
        spec = load_spec(name)
        rows.append(
            {
                "name": name,
                "kind": spec.kind,
                "dof": len(spec.actuated_joints),
                "joints": len(spec.actuated_joints) + len(spec.couplings),
                "fingers": spec.fingers,
                "source": str(spec.model_path.relative_to(hand_models_dir().parent)),
                "description": spec.description,
            }
        )
    if args.joints:
        for row in rows:
            row["joint_limits"] = joint_limits(row["name"])
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print(f"{'name':<16}{'kind':<9}{'dof':>4}{'joints':>8}  {'fingers':<40}source")
    for r in rows:
        fingers = ",".join(r["fingers"])
        print(f"{r['name']:<16}{r['kind']:<9}{r['dof']:>4}{r['joints']:>8}  {fingers:<40}{r['source']}")
    for r in rows if args.joints else []:
        print(f"\n{r['name']}: {'joint':<28}{'universal':<20}{'unit':<6}{'lower':>9}{'upper':>9}")
        for j in r["joint_limits"]:
            row = f"{j['joint']:<28}{j['universal']:<20}{j['unit']:<6}{j['lower']:>9.4g}{j['upper']:>9.4g}"
            print(" " * (len(r["name"]) + 2) + row)
    return 0


def joint_limits(hand: str) -> list[dict]:
    """A hand's actuated joints as a dataset records them: the spec's name, its universal joint, the unit
    (`m` for a prismatic joint, else `rad`) and the model's limits."""
    from lerobot_opfa.hands.registry import load_hand

    model = load_hand(hand)
    prismatic = model.prismatic_mask.tolist()
    return [
        {"joint": name, "universal": universal, "unit": "m" if slides else "rad", "lower": low, "upper": high}
        for name, universal, slides, low, high in zip(
            model.joint_names,
            model.universal_names,
            prismatic,
            model.lower.tolist(),
            model.upper.tolist(),
            strict=True,
        )
    ]


def _cloud(args: argparse.Namespace) -> int:
    import numpy as np
    import torch

    from lerobot_opfa.hands.registry import load_hand

    hand = load_hand(args.hand)
    q = hand.sample_joints(args.batch, torch.Generator().manual_seed(args.seed))
    cloud = hand.point_cloud(q, args.n_points, seed=args.seed)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(
        args.out,
        points=cloud.points.cpu().numpy().astype(np.float32),
        labels=cloud.labels.cpu().numpy().astype(np.int64),
        joints=cloud.joints.cpu().numpy().astype(np.float32),
        joint_names=np.array(hand.joint_names),
    )
    print(f"{args.out}: {args.batch} clouds of {args.n_points} points of '{hand.name}' ({hand.dof} DoF)")
    return 0


def _show(args: argparse.Namespace) -> int:
    import torch

    from lerobot_opfa.hands.plot import plot_clouds
    from lerobot_opfa.hands.registry import load_hand

    hand = load_hand(args.hand)
    if args.joints == "random":
        q = hand.sample_joints(1, torch.Generator().manual_seed(args.seed))
    else:
        q = hand.pose(args.joints)[None]
    cloud = hand.point_cloud(q, args.n_points, seed=args.seed)
    clouds = {args.joints: (cloud.points[0].cpu().numpy(), cloud.labels[0].cpu().numpy())}
    print(plot_clouds(clouds, args.out, title=f"{hand.name}: {hand.spec.description}"))
    return 0
