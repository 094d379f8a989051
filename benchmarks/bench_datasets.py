"""In-distribution success of single-hand policies trained on datasets as a LeRobot rig records them: (a)
from depth-map features through the depth step, (b) from an RGB camera alone.

Per task and hand, `--demos` episodes recorded by the expert teleoperator with `lerobot-record` on the
`opfa_sim` rig (the `front` camera in depth and colour, LeRobot's video encoding; failed expert episodes
dropped with `lerobot-edit-dataset`), in `mid_center`. Then:
- depth: the clouds made once through the depth step (`dataset clouds`), a policy trained on them with
  `lerobot-opfa train`, evaluated with `lerobot-eval --env.obs_type=pointcloud` (the env's clouds from the
  same camera and code). Beside it, training samples/s of the depth path (`lerobot-train` on the depth
  video, clouds made per sample by the step) against the point-cloud path (`lerobot-opfa train` on the
  clouds), measured on the same data in the same run (`bench_training.train`: LeRobot's step times).
- rgb: a policy trained on the colour video (`--policy.visual_inputs=rgb`, with its default `image_goal`;
  `lerobot-opfa train`, frames decoded once), evaluated with `lerobot-eval --env.obs_type=rgb`.
Every run also reports `follows_object` (`failures.object_following`): whether its wrist goes where the
object is, which success alone does not tell on press_button; RGB runs `goal_scatter_cm`
(`failures.image_goal_scatter`): how precisely their features place the object from the first picture.

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_datasets.py [--work outputs/datasets] [--epochs 30]

Resumable: each stage's output, wall time and commit are kept under `--work` (`bench_rig.Stages`).
Results: benchmarks/results/datasets.json (a list of runs) and datasets.png.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import matplotlib.pyplot as plt  # noqa: E402
from bench_rig import BIN, EVAL_SEED, REGION, RESULTS, Stages, record, success_bars  # noqa: E402
from bench_training import train as timed_training  # noqa: E402

EPISODE_S = {"press_button": 4.5, "lift": 6.0}
"""Recorded episode length: the task's steps (80 and 100) at 20 Hz, with room for the expert to finish."""
N_POINTS = 256
POLICY = ["--policy.type=opfa", "--policy.action_space=raw", "--policy.pointcloud_widths=[32,64,128]",
          "--policy.optimizer_lr=3e-4", "--policy.device=cpu", "--policy.push_to_hub=false",
          "--batch_size=32", "--wandb.enable=false", "--seed=0"]  # fmt: skip
FOLLOWING_EPISODES, FOLLOWING_SEED = 20, 5000
GOAL_EPISODES, GOAL_SEED = 40, 7000
TRAIN_ENV = {**os.environ, "OMP_NUM_THREADS": "1"}
"""One torch thread: other jobs share the 2 cores during the run, where two threads collapse."""


def train_and_eval(stages: Stages, name: str, data: Path, flags: list[str], epochs: int, eval_env: dict,
                   task: str, hand: str, episodes: int, reported: tuple[str, ...] = ()) -> dict:  # fmt: skip
    """`eval_env`: the `opfa` env's settings beyond task, hand and region, for lerobot-eval and
    `following` alike; `reported`: policy settings copied into the run from the trained checkpoint."""
    frames = json.loads((data / "meta" / "info.json").read_text())["total_frames"]
    steps = math.ceil(epochs * frames / 32)
    out, evaluation = stages.work / f"train_{name}", stages.work / f"eval_{name}"
    command = [
        str(BIN / "lerobot-opfa"), "train", *POLICY, *flags, f"--dataset.repo_id=local/{data.name}",
        f"--dataset.root={data}", f"--steps={steps}", f"--save_freq={steps}", f"--output_dir={out}",
        f"--policy.scheduler_warmup_steps={min(500, steps // 10)}", f"--policy.scheduler_decay_steps={steps}",
        f"--log_freq={max(1, steps // 20)}",
    ]  # fmt: skip
    stages.run(f"train_{name}", [out], command, env=TRAIN_ENV)
    model = out / "checkpoints" / "last" / "pretrained_model"
    lerobot_eval = [
        str(BIN / "lerobot-eval"), f"--policy.path={model}", "--policy.device=cpu", "--env.type=opfa",
        f"--env.task={task}", f"--env.hand={hand}", f"--env.regions={REGION}",
        *(f"--env.{key}={value}" for key, value in eval_env.items()),
        f"--eval.n_episodes={episodes}", "--eval.batch_size=1", f"--seed={EVAL_SEED}",
        f"--output_dir={evaluation}",
    ]  # fmt: skip
    stages.run(f"eval_{name}", [evaluation], lerobot_eval, env=TRAIN_ENV)
    overall = json.loads((evaluation / "eval_info.json").read_text())["overall"]
    trained = json.loads((model / "config.json").read_text())
    return {
        "successes": round(overall["pc_success"] * overall["n_episodes"] / 100),
        "episodes": overall["n_episodes"],
        "epochs": epochs,
        "train_steps": steps,
        "frames": frames,
        "train_minutes": round(stages.done[f"train_{name}"]["wall_s"] / 60, 2),
        **following(stages, name, model, task, hand, eval_env),
        **{key: trained[key] for key in reported},
    }


def following(stages: Stages, name: str, model: Path, task: str, hand: str, eval_env: dict) -> dict:
    """`failures.object_following` over FOLLOWING_EPISODES fresh episodes (kept in stages.json): whether
    the policy's wrist goes where the object is, which press_button's 6 cm cap lets a blind policy pass."""
    from lerobot_opfa.envs.config import OpfaEnvConfig
    from lerobot_opfa.experiments.failures import object_following

    config = OpfaEnvConfig(task=task, hand=hand, regions=REGION, **eval_env)
    return stages.measure(
        f"following_{name}", lambda: object_following(model, config, FOLLOWING_EPISODES, FOLLOWING_SEED)
    )


def goal_scatter(stages: Stages, name: str, task: str, hand: str) -> dict:
    """`failures.image_goal_scatter` over GOAL_EPISODES resets (kept in stages.json): how precisely the
    trained RGB features place the object, beside `follows_object`, where the policy then goes."""
    from lerobot_opfa.envs.config import OpfaEnvConfig
    from lerobot_opfa.experiments.failures import image_goal_scatter

    model = stages.work / f"train_{name}" / "checkpoints" / "last" / "pretrained_model"
    config = OpfaEnvConfig(task=task, hand=hand, regions=REGION, obs_type="rgb")
    return stages.measure(f"goal_{name}", lambda: image_goal_scatter(model, config, GOAL_EPISODES, GOAL_SEED))


def speeds(stages: Stages, recorded: Path, clouds: Path, calibration: Path, steps: int) -> dict:
    """Samples/s of the depth path and of the point-cloud path on the same demos (kept in stages.json)."""

    def measure() -> dict:
        policy = [*POLICY, f"--policy.cloud_points={N_POINTS}"]
        with tempfile.TemporaryDirectory() as tmp:
            depth = timed_training(recorded, Path(tmp) / "depth", ("lerobot-train", 0, 1, False), steps, 3,
                                   [*policy, f"--policy.cameras={calibration}"])  # fmt: skip
            cloud = timed_training(clouds, Path(tmp) / "cloud", ("lerobot-opfa train", 0, 1, False), steps, 3,
                                   policy)  # fmt: skip
        return {"depth": depth, "pointcloud": cloud}

    measured = stages.measure(f"speed_{recorded.name}", measure)
    return {
        "depth_samples_per_s": round(measured["depth"]["samples_per_s"], 1),
        "pointcloud_samples_per_s": round(measured["pointcloud"]["samples_per_s"], 1),
        "speed_torch_threads": 1,
    }


def plot(runs: list[dict], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(7, 3.6))
    pairs = list(dict.fromkeys((r["task"], r["hand"]) for r in runs))
    width = 0.38
    for i, (observation, target) in enumerate((("depth", 0.8), ("rgb", 0.6))):
        measured = {(r["task"], r["hand"]): r for r in runs if r["observation"] == observation}
        placed = {j + (i - 0.5) * width: measured[pair] for j, pair in enumerate(pairs) if pair in measured}
        counts = [(run["successes"], run["episodes"]) for run in placed.values()]
        success_bars(ax, list(placed), counts, width, f"{observation} (target {target:.0%})")
        for x, run in placed.items():
            if "follows_object" in run:
                ax.text(x, 1.05, f"{run['follows_object']:.2f}", ha="center", fontsize=7)
    ax.axhline(0.8, color="C0", linestyle="--", linewidth=1)
    ax.axhline(0.6, color="C1", linestyle="--", linewidth=1)
    ax.set_xticks(range(len(pairs)), [f"{hand}\n{task}" for task, hand in pairs])
    ax.set_ylim(0, 1.25)
    ax.set_ylabel(f"success in lerobot-eval ({REGION})")
    ax.set_title(
        "single-hand policies from lerobot-record datasets: depth vs RGB\n(above the bars: how far the wrist "
        "follows the object, 1 = wherever it is, 0 = blind)", fontsize=9,
    )  # fmt: skip
    ax.legend(loc="upper center", ncol=2, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--hands", default="umi,inspire")
    parser.add_argument("--tasks", default="press_button,lift")
    parser.add_argument("--observations", default="rgb,depth")
    parser.add_argument("--demos", type=int, default=20)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--epochs", type=int, default=30)
    parser.add_argument("--speed-steps", type=int, default=15)
    parser.add_argument("--work", type=Path, default=Path("outputs/datasets"))
    parser.add_argument(
        "--only-done",
        action="store_true",
        help="report the runs already evaluated (measuring their following and goal scatter where missing)",
    )
    args = parser.parse_args()
    runs = []
    for task in args.tasks.split(","):
        stages = Stages(args.work.resolve() / task)
        for hand in args.hands.split(","):
            if args.only_done and f"record_{hand}" not in stages.done:
                continue
            recorded = record(stages, task, hand, args.demos, EPISODE_S[task])
            calibration = stages.work / f"rig_{hand}" / "opfa_sim_cameras.yaml"
            kept = json.loads((recorded / "meta" / "info.json").read_text())["total_episodes"]
            base = {"hand": hand, "task": task, "demos": kept, "region": REGION, "action_space": "raw"}
            for observation in args.observations.split(","):
                name = f"{hand}_{observation}"
                if args.only_done and f"eval_{name}" not in stages.done:
                    continue
                if observation == "rgb":
                    run = train_and_eval(stages, name, recorded, ["--policy.visual_inputs=rgb"], args.epochs,
                                         {"obs_type": "rgb"}, task, hand, args.episodes,
                                         ("image_backbone", "image_goal"))  # fmt: skip
                    run |= goal_scatter(stages, name, task, hand)
                else:
                    clouds = stages.work / "data" / f"{hand}_clouds"
                    stages.run(f"clouds_{hand}", [clouds], [
                        str(BIN / "lerobot-opfa"), "dataset", "clouds", "--input", str(recorded), "--output",
                        str(clouds), "--cameras", str(calibration), "--n-points", str(N_POINTS)])  # fmt: skip
                    run = train_and_eval(stages, name, clouds, [], args.epochs, {"n_points": N_POINTS}, task,
                                         hand, args.episodes)  # fmt: skip
                    run["clouds_minutes"] = round(stages.done[f"clouds_{hand}"]["wall_s"] / 60, 2)
                    run |= speeds(stages, recorded, clouds, calibration, args.speed_steps)
                runs.append({**base, "observation": observation, **run})
                print(json.dumps(runs[-1]), flush=True)
                RESULTS.mkdir(parents=True, exist_ok=True)
                commits = {s["commit"] for s in stages.done.values() if isinstance(s, dict) and "commit" in s}
                runs[-1]["commits"] = sorted(commits)
                (RESULTS / "datasets.json").write_text(json.dumps(runs, indent=2))
                plot(runs, RESULTS / "datasets.png")


if __name__ == "__main__":
    main()
