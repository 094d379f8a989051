"""`lerobot-opfa galr ...`: list the packaged checkpoints, pretrain, evaluate, embed joints, decode latents.

A checkpoint is named as `frozen.load_galr` takes it: a packaged name (`galr list`), a folder or a Hub
repo id. Torch and the model load only in the commands that use them."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from lerobot_opfa.flags import non_negative_float, positive_float, positive_int
from lerobot_opfa.galr import checkpoints

if TYPE_CHECKING:
    from lerobot_opfa.galr.model import GalrConfig

CHECKPOINT_HELP = "a packaged name (see `galr list`), a checkpoint folder or a Hub repo id"


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    galr = subparsers.add_parser("galr", help="GaLR: pretrain, evaluate, embed, decode").add_subparsers(
        dest="galr_command", required=True
    )
    galr.add_parser("list", help="the packaged GaLR checkpoints").set_defaults(func=_list)

    pre = galr.add_parser("pretrain", help="pretrain GaLR on random reachable states of the hands")
    pre.add_argument(
        "--hands",
        help="'all' (the built-ins, the default; with --resume the run's own) or comma-separated names / "
        "spec paths; with --init, '+SPEC,...' adds hands to the checkpoint's own",
    )
    pre.add_argument(
        "--init",
        help=f"fine-tune this trained GaLR on new hands instead of starting over ({CHECKPOINT_HELP})",
    )
    pre.add_argument(
        "--anchor",
        type=non_negative_float,
        default=1.0,
        help="with --init: weight of keeping its own hands' latents",
    )
    pre.add_argument("--steps", type=positive_int, default=3000)
    pre.add_argument("--batch-size", type=positive_int, default=44)
    pre.add_argument(
        "--shares",
        choices=("dof", "even"),
        help="batch shares per hand: by joint count (default), or equal (default with --init: a 1-joint "
        "gripper the checkpoint already knows to 0.1 deg keeps it only with its share of every batch)",
    )
    pre.add_argument("--lr", type=positive_float, default=1e-3)
    pre.add_argument("--output-dir", type=Path, required=True)
    pre.add_argument("--resume", action="store_true")
    pre.add_argument(
        "--max-minutes", type=positive_float, help="stop (annealed and saved) after this much wall time"
    )
    pre.add_argument("--validate-every", type=positive_int, default=250)
    pre.add_argument("--save-every", type=positive_int, default=500)
    pre.add_argument("--seed", type=int, default=0)
    pre.add_argument("--wandb", action="store_true", help="log scalars to Weights & Biases too")
    pre.add_argument("--push-to-hub", metavar="REPO", help="push the final checkpoint to this Hub repo")
    pre.add_argument(
        "--model", nargs="*", default=[], metavar="KEY=VALUE",
        help="GalrConfig overrides, e.g. encoder=pointnet semantic_embedding=none decoder=per_embodiment",
    )  # fmt: skip
    pre.set_defaults(func=_pretrain)

    ev = galr.add_parser(
        "eval", help="joint RMSE, fingertip error and throughput per hand on held-out states"
    )
    ev.add_argument("--checkpoint", required=True, help=CHECKPOINT_HELP)
    ev.add_argument(
        "--hands", default="all", help="'all' (the checkpoint's registry) or comma-separated names"
    )
    ev.add_argument("--states", type=positive_int, default=256, help="held-out states per hand")
    ev.add_argument("--seed", type=int, default=1)
    ev.add_argument("--json", type=Path, required=True)
    ev.add_argument("--plot", type=Path, help="bar chart of the per-hand errors")
    ev.add_argument("--clouds", type=Path, help="picture of original vs decoded clouds for a few states")
    ev.set_defaults(func=_eval)

    curves = galr.add_parser("curves", help="plot validation RMSE against training time for pretraining runs")
    curves.add_argument(
        "runs", nargs="+", help="run directories (each with metrics.jsonl), LABEL=DIR to name one"
    )
    curves.add_argument("--out", type=Path, required=True)
    curves.set_defaults(func=_curves)

    embed = galr.add_parser(
        "embed",
        help="joint vectors (.npy, (B, dof) in the spec's actuated-joint order, see `hands list`) -> latents "
        "(.npy, (B, d))",
    )
    embed.add_argument("--checkpoint", required=True, help=CHECKPOINT_HELP)
    embed.add_argument("--hand", required=True)
    embed.add_argument("--joints", type=Path, required=True)
    embed.add_argument("--out", type=Path, required=True)
    embed.set_defaults(func=_embed)

    decode = galr.add_parser(
        "decode", help="latents (.npy, (B, d)) -> the hand's joint vectors (.npy, (B, dof))"
    )
    decode.add_argument("--checkpoint", required=True, help=CHECKPOINT_HELP)
    decode.add_argument("--hand", required=True)
    decode.add_argument("--latents", type=Path, required=True)
    decode.add_argument("--out", type=Path, required=True)
    decode.set_defaults(func=_decode)


def _list(args: argparse.Namespace) -> int:
    for entry in checkpoints.listing():
        print(f"{entry['name']:<9}{entry['description']}\n{'':<9}{entry['path']}")
        print(f"{'':<9}hands: {', '.join(entry['hands'])}")
    print("a hand one lacks is added in minutes: lerobot-opfa galr pretrain --init NAME --hands +HAND")
    return 0


def parse_overrides(pairs: list[str]) -> GalrConfig:
    """`key=value` strings -> a GalrConfig, with values typed like the fields' defaults."""
    from lerobot_opfa.galr.model import GalrConfig

    defaults = GalrConfig()
    values = {}
    for pair in pairs:
        key, sep, raw = pair.partition("=")
        if not sep or key not in {f.name for f in dataclasses.fields(GalrConfig)} or key == "hands":
            raise ValueError(f"--model {pair!r}: expected KEY=VALUE with KEY a GalrConfig field")
        default = getattr(defaults, key)
        kind = type(default[0]) if isinstance(default, tuple) else type(default)
        try:
            parsed = tuple(kind(x) for x in raw.split(",")) if isinstance(default, tuple) else kind(raw)
        except ValueError:
            raise ValueError(
                f"--model {pair!r}: {key} takes {kind.__name__} values (default {default})"
            ) from None
        values[key] = parsed
    return GalrConfig(**values)


def _hand_list(hands: str, available: list[str]) -> list[str]:
    return available if hands == "all" else hands.split(",")


def _pretrain(args: argparse.Namespace) -> int:
    from lerobot_opfa.galr.train import PretrainConfig, pretrain
    from lerobot_opfa.hands.registry import builtin_hands

    asked = args.hands or ("" if args.resume else "all")  # resuming without --hands: the run's own
    if asked.startswith("+") and not args.init:
        raise ValueError("--hands +SPEC adds hands to a trained GaLR: name it with --init")
    if args.init and args.model:
        raise ValueError("--init keeps the checkpoint's architecture: leave out --model")
    if asked.startswith("+"):
        hands = asked[1:].split(",")
    else:
        hands = _hand_list(asked, list(builtin_hands())) if asked else None
    config = PretrainConfig(
        output_dir=args.output_dir,
        hands=hands,
        init=args.init,
        anchor=args.anchor,
        steps=args.steps,
        batch_size=args.batch_size,
        shares=args.shares or ("even" if args.init else "dof"),
        lr=args.lr,
        validate_every=args.validate_every,
        save_every=args.save_every,
        max_minutes=args.max_minutes,
        seed=args.seed,
        resume=args.resume,
        wandb=args.wandb,
        push_to_hub=args.push_to_hub,
        model=parse_overrides(args.model),
    )
    pretrain(config)
    print(f"GaLR checkpoint: {args.output_dir}")
    return 0


def _eval(args: argparse.Namespace) -> int:
    from lerobot_opfa.galr.evaluate import evaluate, plot_errors, plot_reconstructions

    galr = checkpoints.load(args.checkpoint)
    hands = _hand_list(args.hands, galr.config.hand_names)
    report = evaluate(galr, hands, args.states, args.seed, out=args.json)
    print(f"mean joint RMSE {report['mean']['joint_rmse_deg']:.2f} deg, "
          f"mean fingertip error {report['mean']['fingertip_error_mm']:.2f} mm -> {args.json}")  # fmt: skip
    if args.plot:
        print(plot_errors(report, args.plot))
    if args.clouds:
        print(plot_reconstructions(galr, hands, args.clouds, seed=args.seed))
    return 0


def _curves(args: argparse.Namespace) -> int:
    from lerobot_opfa.galr.evaluate import plot_training_curves

    runs = dict(r.split("=", 1) if "=" in r else (Path(r).name, r) for r in args.runs)
    print(plot_training_curves({label: Path(run) for label, run in runs.items()}, args.out))
    return 0


def _array(path: Path, what: str, width: int, names: str):
    """A (B, width) float array from a .npy file, or a one-line error saying what was expected."""
    import numpy as np
    import torch

    if not path.is_file():
        raise ValueError(f"{path}: no such file ({what}: a .npy array of shape (B, {width}))")
    try:
        array = np.load(path)
    except (ValueError, OSError) as err:
        raise ValueError(f"{path} is not a .npy array ({err}); {what}: shape (B, {width})") from None
    if not isinstance(array, np.ndarray):
        raise ValueError(f"{path} is an .npz archive, not a .npy array; {what}: shape (B, {width})")
    if array.ndim == 1:
        array = array[None]
    if array.ndim != 2 or array.shape[1] != width:
        raise ValueError(f"{path} holds shape {array.shape}; {what} need shape (B, {width}): {names}")
    return torch.from_numpy(array).float()


def _embed(args: argparse.Namespace) -> int:
    import numpy as np
    import torch

    galr = checkpoints.load(args.checkpoint)
    hand = galr.hand(args.hand)[0]
    q = _array(args.joints, f"joints of '{hand.name}'", hand.dof, ", ".join(hand.joint_names))
    hand.check_within_limits(q, str(args.joints))
    with torch.no_grad():
        z = galr.encode_joints(args.hand, q)
    np.save(args.out, z.cpu().numpy())
    print(f"{args.out}: latents {tuple(z.shape)}")
    return 0


def _decode(args: argparse.Namespace) -> int:
    import numpy as np
    import torch

    galr = checkpoints.load(args.checkpoint)
    galr.hand(args.hand)  # an unknown hand is an error before anything runs
    dim = galr.config.latent_dim
    z = _array(args.latents, "latents", dim, f"{dim} entries from `galr embed` with this checkpoint")
    if not z.isfinite().all():
        rows = int((~z.isfinite()).any(1).sum())
        raise ValueError(f"{args.latents}: {rows} of {len(z)} latents are not finite (NaN or inf)")
    with torch.no_grad():
        q = galr.decode(z, args.hand)
    np.save(args.out, q.cpu().numpy())
    print(f"{args.out}: joints {tuple(q.shape)}")
    return 0
