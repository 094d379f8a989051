"""Robots that differ in arm, hand and rate co-train: a UR5 with an Inspire hand at 30 fps and a Panda with a
umi gripper at 10 fps, each with its scripted demos of `lift` in its own region of the table (the paper's
spatial split), in the simulator with the hand on the arm (`sim demos --arm`: the datasets hold the arms'
joints as their models name them, at the robots' own rates).

Conditions (`--conditions`):
- `opfa`: one policy co-trained on both robots (`dataset merge` reads each arm's joints as the wrist's pose
  and resamples both to the lowest rate, 10 fps; GaLR latents for the hands), run on each robot at 10 fps.
- `naive_cotrain`: the same co-training with the hands as padded universal joints (`per_embodiment`); the
  body is the same wrist pose (a merge of the arms' joint columns padded is not built).
- `wo_cotrain` ("alone"): each robot's own policy on its own demos, its own joints (`raw`), at its own rate.
- `untrained`: the control, OPFA's policy on the merged demos as initialised.

Every (robot, region, condition) cell is `--episodes` seeded `lerobot-eval` episodes with `--env.arm`, in the
robot's own region and in the other robot's. Through the experiment runner (`experiments.jobs`): each step
is idempotent, so an interrupted run resumes; two runs with different `--conditions` share the demos (run
`--stage demos` first). One torch thread per process.

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_cross_rig.py [--stage demos|all]
        [--conditions opfa,naive_cotrain,wo_cotrain,untrained] [--demos 24] [--epochs 50] [--episodes 50]
        [--work outputs/cross_rig]

benchmarks/results/cross_rig.json (`runs` of {robot, arm, hand, fps, camera, trained_on, region, condition,
action_space, successes, episodes, deploy}, `region` "own" or "other"; with `--outcomes N`, `outcomes` of
the other-region cells: N episodes rerun through LeRobot's loop, counted as success, never_touched (the hand
never touched the object) or touched_failed) and cross_rig.png are rewritten after every evaluation (under a
lock in `--work`).
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from lerobot_opfa.experiments.jobs import (  # noqa: E402
    CONDITIONS,
    Demos,
    Evaluation,
    Training,
    Workspace,
    write_json,
)
from lerobot_opfa.experiments.scales import fixed_epochs  # noqa: E402

RESULTS = Path(__file__).parent / "results"
TASK = "lift"
SHORT = {"wo_cotrain": "alone", "naive_cotrain": "naive", "opfa": "OPFA", "untrained": "control"}
"""Conditions as the plot names them (`control`: OPFA untrained)."""
MERGED_FPS = 10
"""The merge's rate: the lowest of the robots' (`dataset merge`'s default)."""


@dataclass(frozen=True)
class Robot:
    name: str
    arm: str
    hand: str
    fps: int
    region: str


ROBOTS = (
    Robot("ur5_inspire", "ur5", "inspire", 30, "mid_left"),
    Robot("panda_umi", "panda", "umi", 10, "mid_right"),
)


def robot_demos(robot: Robot, episodes: int) -> Demos:
    return Demos(TASK, robot.hand, (robot.region,), episodes, arm=robot.arm, fps=robot.fps)


def cells(demos: int, conditions: list[str]) -> list[tuple[Training, Robot, Robot, int]]:
    """(training, robot evaluated, the robot whose region it is evaluated in, the rate it runs at)."""
    both = tuple(robot_demos(robot, demos) for robot in ROBOTS)
    out = []
    for condition in conditions:
        for robot in ROBOTS:
            alone = condition == "wo_cotrain"
            training = Training(condition, (robot_demos(robot, demos),) if alone else both)
            fps = robot.fps if alone else MERGED_FPS
            out += [(training, robot, place, fps) for place in ROBOTS]
    return out


def record(out: Path, lock: Path, row: dict, commit: str | None, outcomes: dict | None = None) -> list[dict]:
    """Every run in `out` with `row` in place of the same cell's (and its failure modes, `outcomes`, in place
    of theirs) and the `commit` the cell was evaluated at, read and written holding the file `lock`: two
    runs of this benchmark may finish cells at once."""
    key = ("robot", "region", "condition")
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(lock, "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        report = json.loads(out.read_text()) if out.exists() else {"runs": []}
        runs = [r for r in report["runs"] if any(r[k] != row[k] for k in key)] + [row]
        order = {c: i for i, c in enumerate(CONDITIONS)}
        runs.sort(key=lambda r: (r["robot"], r["region"] != "own", order[r["condition"]]))
        report["runs"] = runs
        report["commit"] = commit
        if outcomes is not None:
            cell = {k: row[k] for k in key}
            kept = [o for o in report.get("outcomes", []) if any(o[k] != cell[k] for k in key)]
            report["outcomes"] = [*kept, {**cell, **outcomes}]
        write_json(out, report)
    return runs


def plot(runs: list[dict], path: Path) -> None:
    """Per robot, its success in its own region and in the other robot's, one bar per condition."""
    fig, axes = plt.subplots(1, len(ROBOTS), figsize=(12, 4.6), sharey=True)
    colours = {
        "opfa": "tab:blue",
        "naive_cotrain": "tab:orange",
        "wo_cotrain": "tab:green",
        "untrained": "0.6",
    }
    for ax, robot in zip(axes, ROBOTS, strict=True):
        mine = [r for r in runs if r["robot"] == robot.name]
        for i, run in enumerate(mine):
            rate = 100 * run["successes"] / run["episodes"]
            x = i + (run["region"] == "other")
            ax.bar(x, rate, color=colours[run["condition"]], hatch="//" if run["region"] == "other" else None)
            ax.text(x, rate + 1, f"{run['successes']}/{run['episodes']}", ha="center", fontsize=8)
        ax.set_xticks([i + (r["region"] == "other") for i, r in enumerate(mine)])
        ax.set_xticklabels([f"{SHORT[r['condition']]}\n{r['fps']} fps" for r in mine], fontsize=8)
        ax.set_title(f"{robot.arm} + {robot.hand} ({robot.fps} fps demos in {robot.region})")
        ax.axhline(80, color="grey", lw=0.8, ls=":")
    axes[0].set(ylabel="lift success (%)", ylim=(0, 110))
    fig.suptitle(
        "lift, two robots of different arms, hands and rates: in each panel the robot's own region, then "
        "(hatched) the other robot's"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--stage", choices=["demos", "all"], default="all")
    parser.add_argument("--conditions", default="opfa,naive_cotrain,wo_cotrain,untrained")
    parser.add_argument("--demos", type=int, default=24)
    parser.add_argument("--epochs", type=int, default=50)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--work", type=Path, default=Path("outputs/cross_rig"))
    parser.add_argument("--galr", default="default")
    parser.add_argument("--results", type=Path, default=RESULTS)
    parser.add_argument("--name", default="cross_rig", help="results as NAME.json and NAME.png")
    parser.add_argument(
        "--outcomes", type=int, default=0,
        help="rerun this many episodes of each cell in the other robot's region to tell how they fail",
    )  # fmt: skip
    args = parser.parse_args()
    scale = fixed_epochs(f"cross_rig-{args.demos}x{args.epochs}", args.demos, args.epochs, args.episodes)
    workspace = Workspace(args.work, scale, args.galr, threads=1)
    for robot in ROBOTS:
        workspace.demos(robot_demos(robot, args.demos))
    if args.stage == "demos":
        return
    out, picture = args.results / f"{args.name}.json", args.results / f"{args.name}.png"
    for training, robot, place, fps in cells(args.demos, args.conditions.split(",")):
        evaluation = Evaluation(training, TASK, robot.hand, (place.region,), arm=robot.arm, fps=fps)
        result = workspace.evaluate(evaluation)
        row = {
            "robot": robot.name,
            "arm": robot.arm,
            "hand": robot.hand,
            "fps": fps,
            "camera": f"point cloud, {scale.n_points} points sampled from the scene's geometry",
            "trained_on": [d.name for d in training.demos],
            "region": "own" if place == robot else "other",
            "condition": training.condition,
            "action_space": CONDITIONS[training.condition],
            "successes": sum(result["successes"]),
            "episodes": len(result["successes"]),
            "deploy": "lerobot-eval",
        }
        print(
            json.dumps(row), f"(commit {result['commit']}, training {result['training_commit']})", flush=True
        )
        outcomes = None
        if args.outcomes and place != robot:
            outcomes = {"episodes": args.outcomes, **workspace.failure_modes(evaluation, args.outcomes)}
        plot(record(out, args.work / "results.lock", row, result["commit"], outcomes), picture)


if __name__ == "__main__":
    main()
