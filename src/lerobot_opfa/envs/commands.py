"""`lerobot-opfa sim ...`: record scripted demonstrations, picture a scene, list the regions."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from lerobot_opfa.envs import DEFAULT_FPS
from lerobot_opfa.flags import positive_int
from lerobot_opfa.output_folders import check_writable

logger = logging.getLogger(__name__)


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    sim = subparsers.add_parser("sim", help="MuJoCo benchmark: demos, pictures, regions").add_subparsers(
        dest="sim_command", required=True
    )
    demos = sim.add_parser("demos", help="record scripted expert demos as a LeRobotDataset (v3)")
    _scene_args(demos)
    demos.add_argument("--episodes", type=positive_int, required=True)
    demos.add_argument("--output-dir", type=Path, required=True)
    demos.add_argument("--repo-id", help="dataset repo id (default local/opfa_<task>_<hand>)")
    demos.add_argument("--n-points", type=positive_int, default=1024)
    demos.add_argument("--pointcloud-source", choices=["depth", "geometry"], default="depth")
    demos.add_argument("--depth-cameras", default="front", help="comma-separated: front, left, right")
    demos.add_argument("--overwrite", action="store_true", help="replace an existing --output-dir")
    demos.add_argument(
        "--control", choices=["joints", "ee_delta"], default="joints",
        help="joints: absolute wrist pose and hand joints; ee_delta (a gripper): tool steps and a 0..1 grasp "
        "command, state with wrist velocities and a -1..1 gripper reading",
    )  # fmt: skip
    demos.add_argument(
        "--arm", help="mount the hand on this arm (`lerobot-opfa arms list`, or an arm spec path): the "
        "dataset records the arm's joints, as its model names them; default: the floating wrist",
    )  # fmt: skip
    demos.add_argument(
        "--fps", type=positive_int, help="the robot's control and recording rate (default: the simulator's)"
    )
    demos.set_defaults(func=_demos)

    show = sim.add_parser(
        "show", help="a picture of the scene and its point cloud; optionally an expert video"
    )
    _scene_args(show)
    show.add_argument("--out", type=Path, required=True, help="PNG file")
    show.add_argument("--video", type=Path, help="MP4 file for one scripted expert episode")
    show.set_defaults(func=_show)

    sim.add_parser("regions", help="the named table regions").set_defaults(func=_regions)


def _scene_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", required=True)
    parser.add_argument(
        "--hand", required=True,
        help="built-in name or path to a spec.yaml; for a two-hand task (lift_tray) one per side, left "
        "first: inspire+xhand",
    )  # fmt: skip
    parser.add_argument("--regions", default="all", help="comma-separated region names, or 'all'")
    parser.add_argument("--seed", type=int, default=0)


def _demos(args: argparse.Namespace) -> int:
    from lerobot_opfa.envs.demos import record_demos

    check_writable(args.output_dir, "--output-dir", beside=True)  # the dataset is written beside it first
    meta = record_demos(
        args.task, args.hand, args.episodes, args.output_dir, args.regions, args.seed,
        args.repo_id, args.n_points, args.pointcloud_source, args.depth_cameras, args.overwrite, args.control,
        args.arm, args.fps or DEFAULT_FPS,
    )  # fmt: skip
    print(
        f"wrote {args.output_dir}: {meta.total_episodes} episodes, {meta.total_frames} frames of "
        f"{args.task} with {meta.robot_type}"
    )
    return 0


def _show(args: argparse.Namespace) -> int:
    import numpy as np
    from matplotlib.figure import Figure

    from lerobot_opfa.envs.env import OpfaSimEnv
    from lerobot_opfa.envs.experts import ScriptedExpert

    env = OpfaSimEnv(
        args.task,
        args.hand,
        args.regions,
        obs_type="pointcloud",
        n_points=2048,
        depth_cameras="front,left,right",
    )
    obs, info = env.reset(seed=args.seed)
    fig = Figure(figsize=(11, 4.5))
    ax = fig.add_subplot(1, 2, 1)
    ax.imshow(env.render())
    ax.set_title(f"{args.task} / {env.hand_name} / {info['region']}")
    ax.axis("off")
    cloud = obs["pointcloud"].reshape(-1, 3)
    ax = fig.add_subplot(1, 2, 2, projection="3d")
    ax.scatter(*cloud.T, s=1, c=cloud[:, 2], cmap="viridis")
    ax.set_title(f"depth point cloud, three cameras, N = {len(cloud)} (world frame, m)")
    ax.set_box_aspect(np.ptp(cloud, axis=0) + 1e-3)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110, bbox_inches="tight")
    print(args.out)
    if args.video:
        from lerobot.utils.io_utils import write_video

        from lerobot_opfa.envs.demos import failure_reason

        env.reset(seed=args.seed)
        expert, frames, success = ScriptedExpert(env, np.random.default_rng(args.seed)), [env.render()], False
        states = [env.task.env_state(env.scene, env.data)]
        while not (expert.done or success):
            _, _, success, _, _ = env.step(expert.act())
            frames.append(env.render())
            states.append(env.task.env_state(env.scene, env.data))
        args.video.parent.mkdir(parents=True, exist_ok=True)
        write_video(args.video, frames, fps=env.metadata["render_fps"])
        outcome = "succeeded" if success else f"failed: {failure_reason(env, np.stack(states))}"
        print(f"{args.video}: {len(frames)} frames, expert {outcome}")
    env.close()
    return 0


def _regions(args: argparse.Namespace) -> int:
    from lerobot_opfa.envs.regions import REGIONS

    for r in REGIONS.values():
        print(f"{r.name:<14} x {r.x[0]:+.2f}..{r.x[1]:+.2f}  y {r.y[0]:+.2f}..{r.y[1]:+.2f}")
    return 0
