"""The rig path end to end: one policy for two hands, recorded with `lerobot-record` and deployed with
`lerobot-rollout` on the simulated rig, beside the same checkpoint's `lerobot-eval`.

Per hand, `--demos` episodes recorded by the expert teleoperator on the `opfa_sim` rig (RGB + depth from
the `front` camera, LeRobot's depth video); failed expert episodes dropped with `lerobot-edit-dataset`;
the clouds made once through the depth step (`dataset clouds`). Then the hands' clouds merged with the
GaLR, one `galr` policy trained on the merge (`lerobot-opfa train`), and per hand `--episodes` episodes of
`lerobot-rollout --strategy.type=episodic` on the rig (depth frames through the checkpoint's depth step)
and of `lerobot-eval --env.type=opfa` (the env's own clouds), in the same region and seeds.

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_rig.py [--hands umi,inspire] [--task lift]
        [--work outputs/rig] [--name rig]

A two-armed rig is one "hand" of two, left first: `--hands inspire+xhand --task lift_tray --name
rig_two_hands`.

Each stage's output and wall time are kept under `--work`: an interrupted run resumes at the stage it
stopped in. Results: benchmarks/results/rig.json and rig.png.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("HF_HUB_OFFLINE", "1")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from lerobot_opfa.experiments.jobs import source_commit  # noqa: E402
from lerobot_opfa.experiments.report import wilson_interval  # noqa: E402

RESULTS = Path(__file__).parent / "results"
BIN = Path(sys.executable).parent
REGION = "mid_center"
FPS, RECORD_S, EVAL_SEED = 20, 6, 1000
LOOP_HZ = 14.3
"""The slowest loop rate a rollout episode's length covers the task's steps at (the rig counts success
within them, as `lerobot-eval` does): 7 s for a 100-step task; a 5 s episode left the policy 55-85 steps
at the 15 Hz measured."""
ROLLOUT_ENV = {**os.environ, "OMP_NUM_THREADS": "1"}
"""One torch thread in the control loop: on 2 busy cores a loop step of the co-trained policy took 39 ms
with one and 52 ms with two (the rendering and LeRobot's frame writers share the cores)."""


class Stages:
    """Runs each stage once: its wall time and the package's commit are saved when it completes, and a
    stage whose output exists without them was interrupted and is run again from scratch."""

    def __init__(self, work: Path):
        self.work, self.file = work, work / "stages.json"
        work.mkdir(parents=True, exist_ok=True)
        self.done: dict[str, dict] = json.loads(self.file.read_text()) if self.file.exists() else {}

    def run(self, name: str, outputs: list[Path], *commands: list[str], env: dict | None = None) -> None:
        if name in self.done:
            return
        for path in outputs:
            shutil.rmtree(path, ignore_errors=True)
        start = time.perf_counter()
        for command in commands:
            log = self.work / "logs" / f"{name}.log"
            log.parent.mkdir(exist_ok=True)
            print(f"[{name}] {' '.join(command)}", flush=True)
            with log.open("a") as out:
                done = subprocess.run(command, stdout=out, stderr=subprocess.STDOUT, cwd=self.work, env=env)
            if done.returncode != 0:
                sys.exit(f"stage {name} failed (exit {done.returncode}); its log: {log}")
        self.done[name] = {"wall_s": round(time.perf_counter() - start, 1), "commit": source_commit()}
        self.file.write_text(json.dumps(self.done, indent=2))

    def measure(self, name: str, compute: Callable[[], dict]) -> dict:
        """An in-process measurement, made once: its result is kept with the package's commit."""
        if name not in self.done:
            self.done[name] = {**compute(), "commit": source_commit()}
            self.file.write_text(json.dumps(self.done, indent=2))
        return {k: v for k, v in self.done[name].items() if k != "commit"}


def rig_args(task: str, hand: str, calibration: Path, episode_s: float, seed: int) -> list[str]:
    return [
        "--robot.type=opfa_sim",
        f"--robot.hand={hand}",
        f"--robot.task={task}",
        f"--robot.regions={REGION}",
        f"--robot.seed={seed}",
        "--robot.rgb_cameras=front",
        f"--robot.episode_time_s={episode_s}",
        f"--robot.calibration_dir={calibration}",
        f"--dataset.episode_time_s={episode_s}",
        "--dataset.reset_time_s=0",
        f"--dataset.single_task={task.replace('_', ' ')}",
        "--dataset.push_to_hub=false",
    ]


def episodes_log(calibration: Path) -> list[dict]:
    path = calibration / "opfa_sim_episodes.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()]


def record(stages: Stages, task: str, hand: str, demos: int, episode_s: float = RECORD_S) -> Path:
    """The expert's demos of `hand`, failed episodes dropped."""
    work, calibration = stages.work, stages.work / f"rig_{hand}"
    recorded, kept = work / "data" / f"{hand}_recorded", work / "data" / hand
    command = [
        str(BIN / "lerobot-record"),
        *rig_args(task, hand, calibration, episode_s, 0),
        "--teleop.type=opfa_expert",
        f"--dataset.repo_id=local/{hand}_rig",
        f"--dataset.root={recorded}",
        f"--dataset.num_episodes={demos}",
        f"--dataset.fps={FPS}",
    ]
    stages.run(f"record_{hand}", [recorded, calibration], command)
    failed = [o["episode"] for o in episodes_log(calibration) if not o["success"]]
    drop = [
        str(BIN / "lerobot-edit-dataset"),
        f"--repo_id=local/{hand}_rig",
        f"--root={recorded}",
        f"--new_repo_id=local/{hand}",
        f"--new_root={kept}",
        "--operation.type=delete_episodes",
        f"--operation.episode_indices={failed}",
    ]
    if failed:
        stages.run(f"drop_{hand}", [kept], drop)
    return kept if failed else recorded


def deploy_seconds(task: str) -> int:
    from lerobot_opfa.envs.tasks import TASKS

    return math.ceil(TASKS[task].episode_steps / LOOP_HZ)


def evaluate(stages: Stages, task: str, hand: str, model: Path, episodes: int, n_points: int) -> dict:
    work, deploy_s = stages.work, deploy_seconds(task)
    deploy, out, pinned = work / f"deploy_{hand}", work / f"eval_{hand}", work / f"policy_{hand}"
    # the rig's frames reach the policy without their robot: a copy of the checkpoint names it
    pin = [str(BIN / "lerobot-opfa"), "policy", "for-robot", "--policy", str(model), "--hand", hand]
    stages.run(f"pin_{hand}", [pinned], [*pin, "--output", str(pinned)])
    rollout = [
        str(BIN / "lerobot-rollout"),
        *rig_args(task, hand, deploy, deploy_s, EVAL_SEED),
        f"--policy.path={pinned}",
        "--strategy.type=episodic",
        "--strategy.reset_to_initial_position=false",
        f"--dataset.repo_id=local/rollout_{hand}",
        f"--dataset.root={work / 'data' / f'rollout_{hand}'}",
        f"--dataset.num_episodes={episodes}",
        f"--fps={FPS}",
        "--return_to_initial_position=false",
    ]
    stages.run(f"rollout_{hand}", [deploy, work / "data" / f"rollout_{hand}"], rollout, env=ROLLOUT_ENV)
    lerobot_eval = [
        str(BIN / "lerobot-eval"),
        f"--policy.path={model}",
        "--policy.device=cpu",
        "--env.type=opfa",
        f"--env.task={task}",
        f"--env.hand={hand}",
        f"--env.regions={REGION}",
        f"--env.n_points={n_points}",
        f"--eval.n_episodes={episodes}",
        "--eval.batch_size=1",
        f"--seed={EVAL_SEED}",
        f"--output_dir={out}",
    ]
    stages.run(f"eval_{hand}", [out], lerobot_eval)
    outcomes = episodes_log(deploy)
    overall = json.loads((out / "eval_info.json").read_text())["overall"]
    steps = sum(o["steps"] for o in outcomes)
    return {
        "hand": hand,
        "rollout_successes": sum(o["success"] for o in outcomes),
        "rollout_episodes": len(outcomes),
        "eval_successes": round(overall["pc_success"] * overall["n_episodes"] / 100),
        "eval_episodes": overall["n_episodes"],
        "loop_hz": round(steps / (len(outcomes) * deploy_s), 2),
        "target_hz": FPS,
    }


def success_bars(ax, xs: list[float], counts: list[tuple[int, int]], width: float, label: str) -> None:
    """Bars of success rates (successes, episodes) with their 95 % Wilson intervals."""
    rates = [k / n for k, n in counts]
    bounds = [wilson_interval(k, n) for k, n in counts]
    errors = [
        [r - low for r, (low, _) in zip(rates, bounds, strict=True)],
        [high - r for r, (_, high) in zip(rates, bounds, strict=True)],
    ]
    ax.bar(xs, rates, width, yerr=errors, capsize=4, label=label)


def plot(hands: list[dict], task: str, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6, 3.5))
    width = 0.38
    for i, (label, key) in enumerate([("lerobot-rollout on the rig", "rollout"), ("lerobot-eval", "eval")]):
        counts = [(h[f"{key}_successes"], h[f"{key}_episodes"]) for h in hands]
        success_bars(ax, [j + (i - 0.5) * width for j in range(len(hands))], counts, width, label)
    ax.axhline(0.8, color="grey", linestyle="--", linewidth=1)
    ax.set_xticks(range(len(hands)), [h["hand"] for h in hands])
    ax.set_ylim(0, 1.25)
    ax.set_ylabel(f"success ({task}, {REGION})")
    ax.set_title("one opfa policy for both hands,\nrecorded and deployed through LeRobot", fontsize=10)
    ax.legend(loc="upper center", ncol=2, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--hands", default="umi,inspire")
    parser.add_argument("--task", default="lift")
    parser.add_argument("--demos", type=int, default=20)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--epochs", type=int, default=40)
    parser.add_argument("--n-points", type=int, default=256)
    parser.add_argument("--galr", default="long")
    parser.add_argument("--work", type=Path, default=Path("outputs/rig"))
    parser.add_argument("--record-s", type=float, default=RECORD_S, help="a recorded episode's length")
    parser.add_argument("--name", default="rig", help="results file name: benchmarks/results/NAME.{json,png}")
    args = parser.parse_args()
    work = args.work.resolve()
    stages = Stages(work)
    hands = args.hands.split(",")
    clouds = []
    for hand in hands:
        recorded = record(stages, args.task, hand, args.demos, args.record_s)
        cloud = work / "data" / f"{hand}_clouds"
        stages.run(
            f"clouds_{hand}",
            [cloud],
            [
                str(BIN / "lerobot-opfa"),
                "dataset",
                "clouds",
                "--input",
                str(recorded),
                "--output",
                str(cloud),
                "--cameras",
                str(work / f"rig_{hand}" / "opfa_sim_cameras.yaml"),
                "--n-points",
                str(args.n_points),
            ],
        )
        clouds.append(cloud)
    merged = work / "data" / "merged"
    stages.run(
        "merge",
        [merged],
        [
            str(BIN / "lerobot-opfa"),
            "dataset",
            "merge",
            "--inputs",
            *map(str, clouds),
            "--output",
            str(merged),
            "--galr",
            args.galr,
        ],
    )
    frames = json.loads((merged / "meta" / "info.json").read_text())["total_frames"]
    steps = math.ceil(args.epochs * frames / 32)
    train = work / "train"
    stages.run(
        "train",
        [train],
        [
            str(BIN / "lerobot-opfa"),
            "train",
            "--policy.type=opfa",
            "--policy.action_space=galr",
            f"--policy.galr_path={args.galr}",
            "--policy.wrist_normalization=shared",
            "--policy.pointcloud_widths=[32,64,128]",
            "--policy.optimizer_lr=3e-4",
            "--policy.device=cpu",
            "--policy.push_to_hub=false",
            "--dataset.repo_id=local/merged",
            f"--dataset.root={merged}",
            "--batch_size=32",
            f"--steps={steps}",
            f"--policy.scheduler_warmup_steps={min(500, steps // 10)}",
            f"--policy.scheduler_decay_steps={steps}",
            f"--save_freq={steps}",
            f"--log_freq={max(1, steps // 20)}",
            f"--output_dir={train}",
            "--wandb.enable=false",
            "--seed=0",
        ],
    )
    model = train / "checkpoints" / "last" / "pretrained_model"
    results = [evaluate(stages, args.task, hand, model, args.episodes, args.n_points) for hand in hands]
    demos = {h: sum(o["success"] for o in episodes_log(work / f"rig_{h}")) for h in hands}
    report = {
        "hands": results,
        "task": args.task,
        "region": REGION,
        "expert_successes": demos,
        "demos_per_hand": args.demos,
        "merged_frames": frames,
        "train_steps": steps,
        "rollout_episode_s": deploy_seconds(args.task),
        "n_points": args.n_points,
        "galr": args.galr,
        "stages": stages.done,
        "machine": f"{os.cpu_count()} cores, {platform.machine()}",
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{args.name}.json").write_text(json.dumps(report, indent=2))
    plot(results, args.task, RESULTS / f"{args.name}.png")
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
