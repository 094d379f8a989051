"""`lerobot-opfa dataset ...`: merge, clouds, synthetic."""

from __future__ import annotations

import argparse
from pathlib import Path

from lerobot_opfa.flags import positive_int


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    dataset = subparsers.add_parser("dataset", help="cross-embodiment LeRobotDatasets").add_subparsers(
        dest="dataset_command", required=True
    )
    merge = dataset.add_parser("merge", help="per-hand datasets -> one dataset in the universal-joint layout")
    merge.add_argument("--inputs", type=Path, nargs="+", required=True, help="per-hand dataset folders")
    merge.add_argument("--output", type=Path, required=True)
    merge.add_argument(
        "--galr", help="GaLR checkpoint (packaged name, folder or Hub repo id): cache z of every frame"
    )
    merge.add_argument(
        "--joint-maps",
        nargs="+",
        default=[],
        metavar="[INPUT=]MAP",
        help="joint map YAML files for inputs whose entries are not named after their hand's joints "
        "(docs/usage.md); each input takes the map whose entries it has, or the one bound to it as INPUT=MAP "
        "(robots whose entries are named alike)",
    )
    merge.add_argument(
        "--fps",
        type=int,
        help="the merged dataset's rate (default: the lowest input's); inputs at another rate are resampled "
        "by timestamp",
    )
    merge.add_argument(
        "--camera-map",
        nargs="+",
        default=[],
        metavar="ROLE=KEY",
        help="which camera of each input is which: front=observation.images.cam_high "
        "front=observation.images.top merges both as observation.images.front (colour resized to the first's "
        "size; an input with none gets camera_missing.front)",
    )
    merge.add_argument("--repo-id", default="local/opfa_merged")
    merge.add_argument("--overwrite", action="store_true")
    merge.set_defaults(func=_merge)

    clouds = dataset.add_parser(
        "clouds", help="depth dataset -> its clouds, made once through the depth step (fast training)"
    )
    clouds.add_argument("--input", type=Path, required=True)
    clouds.add_argument("--output", type=Path, required=True)
    clouds.add_argument("--cameras", type=Path, required=True, help="camera calibration YAML (docs/usage.md)")
    clouds.add_argument("--n-points", type=positive_int, default=1024)
    clouds.add_argument("--overwrite", action="store_true")
    clouds.set_defaults(func=_clouds)

    synthetic = dataset.add_parser("synthetic", help="a small synthetic per-hand dataset (no simulator)")
    synthetic.add_argument("--hand", required=True)
    synthetic.add_argument("--output", type=Path, required=True)
    synthetic.add_argument("--episodes", type=positive_int, default=4)
    synthetic.add_argument("--frames", type=positive_int, default=50)
    synthetic.add_argument("--n-points", type=positive_int, default=256)
    synthetic.add_argument("--seed", type=int, default=0)
    synthetic.set_defaults(func=_synthetic)


def _merge(args: argparse.Namespace) -> None:
    from lerobot_opfa.datasets.merge import merge_datasets

    out = merge_datasets(
        args.inputs, args.output, args.galr, args.repo_id, args.overwrite, args.joint_maps, args.fps,
        args.camera_map,
    )  # fmt: skip
    print(f"wrote {_summary(out)}" + (f"; latents cached with GaLR {args.galr}" if args.galr else ""))


def _clouds(args: argparse.Namespace) -> None:
    from lerobot_opfa.datasets.clouds import cloud_dataset

    out = cloud_dataset(args.input, args.output, args.cameras, args.n_points, args.overwrite)
    print(f"wrote {_summary(out)}, clouds of {args.n_points} points from the cameras of {args.cameras}")


def _synthetic(args: argparse.Namespace) -> None:
    from lerobot_opfa.datasets.synthetic import write_synthetic_dataset

    write_synthetic_dataset(args.output, args.hand, args.episodes, args.frames, args.n_points, seed=args.seed)
    print(f"wrote {_summary(args.output)}")


def _summary(root: Path) -> str:
    """'<root>: N episodes, M frames of <hands>' from the dataset's own metadata."""
    from lerobot_opfa.datasets.io import read_json
    from lerobot_opfa.features import OBS_EMBODIMENT

    info = read_json(Path(root) / "meta" / "info.json")
    embodiment = info["features"].get(OBS_EMBODIMENT, {}).get("names") or [info.get("robot_type")]
    return (
        f"{root}: {info['total_episodes']} episodes, {info['total_frames']} frames of {', '.join(embodiment)}"
    )
