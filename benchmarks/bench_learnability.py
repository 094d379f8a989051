"""Learnability: in-distribution success of single-hand policies against training length.

For each (hand, task) it records 20 scripted demos in one region, trains a `raw` policy (the hand's own
joints) and a `galr` policy (wrist + GaLR latent) from scratch for each length in `--epochs`, and evaluates
each with `lerobot-eval` on 50 seeded episodes in the same region. A (hand, task, action space) stops at the
first length that reaches 90 %: what the experiments' scales must train at least.

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_learnability.py [--hands umi,inspire,xhand]
        [--tasks press_button,lift] [--spaces raw,galr] [--epochs 10,30,100,300] [--work outputs/learnability]

Every run goes through the experiment runner (`lerobot-opfa train`, then `lerobot-eval`), whose steps are
idempotent: an interrupted benchmark resumes where it stopped. The result list is rewritten after every run:
benchmarks/results/learnability.json and learnability.png.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from lerobot_opfa.experiments.jobs import (  # noqa: E402
    Demos,
    Evaluation,
    Training,
    Workspace,
    galr_identity,
    write_json,
)
from lerobot_opfa.experiments.scales import Scale, fixed_epochs  # noqa: E402
from lerobot_opfa.galr.checkpoints import packaged_path  # noqa: E402

RESULTS = Path(__file__).parent / "results"
TARGET = 0.9
DEMOS, EPISODES, REGION = 20, 50, "mid_center"
CONDITION = {"raw": "wo_cotrain", "galr": "opfa"}


def scale(epochs: int) -> Scale:
    """The `small` scale's policy, trained for exactly `epochs` passes over the demos."""
    return fixed_epochs(f"learnability-{epochs}", DEMOS, epochs, EPISODES)


def run(work: Path, galr: str, hand: str, task: str, space: str, epochs: int) -> dict:
    workspace = Workspace(work / f"epochs-{epochs}", scale(epochs), galr)
    for shared in ("demos", "merged"):  # the same demos (and their latents) for every length
        link = workspace.root / shared
        if not link.exists():
            (work / shared).mkdir(parents=True, exist_ok=True)
            link.symlink_to(Path("..") / shared)
    training = Training(CONDITION[space], (Demos(task, hand, (REGION,), DEMOS),))
    start = time.monotonic()
    trained = workspace.root / "train" / training.name / "checkpoints"
    fresh = not trained.exists()
    workspace.checkpoint(training)
    minutes = (time.monotonic() - start) / 60
    timing = workspace.root / "train" / training.name / "train_minutes.json"
    if fresh:
        timing.write_text(json.dumps(round(minutes, 2)))
    result = workspace.evaluate(Evaluation(training, task, hand, (REGION,)))
    frames = json.loads((workspace.demos(training.demos[0]) / "meta" / "info.json").read_text())[
        "total_frames"
    ]
    return {
        "hand": hand,
        "task": task,
        "action_space": space,
        "epochs": epochs,
        "steps": workspace.scale.steps(frames),
        "successes": sum(result["successes"]),
        "episodes": len(result["successes"]),
        "train_minutes": json.loads(timing.read_text()) if timing.exists() else None,
    }


def _key(run: dict) -> tuple:
    return run["hand"], run["task"], run["action_space"], run["epochs"]


def record(out: Path, result: dict) -> list[dict]:
    """Every run in `out` with `result` in place of its cell's: the file is read again just before it is
    written, so runs of this benchmark that another process recorded meanwhile stay."""
    runs = json.loads(out.read_text()) if out.exists() else []
    runs = [r for r in runs if _key(r) != _key(result)] + [result]
    write_json(out, runs)
    return runs


def plot(runs: list[dict], path: Path) -> None:
    """One panel per task: each hand's success as a bar per (action space, epochs) measured."""
    tasks = sorted({r["task"] for r in runs})
    fig, axes = plt.subplots(1, len(tasks), figsize=(5.5 * len(tasks), 4.6), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        rows = [r for r in runs if r["task"] == task]
        hands = sorted({r["hand"] for r in rows})
        series = sorted({(r["action_space"], r["epochs"]) for r in rows}, key=lambda s: (s[0] != "raw", s[1]))
        width = 0.8 / len(series)
        for i, (space, epochs) in enumerate(series):
            rate = {
                r["hand"]: 100 * r["successes"] / r["episodes"]
                for r in rows
                if (r["action_space"], r["epochs"]) == (space, epochs)
            }
            at = [h for h, hand in enumerate(hands) if hand in rate]
            ax.bar([h + (i - (len(series) - 1) / 2) * width for h in at], [rate[hands[h]] for h in at], width,
                   label=f"{space}, {epochs} epochs", hatch="//" if space == "raw" else None)  # fmt: skip
        ax.axhline(100 * TARGET, color="grey", lw=0.8, ls=":")
        ax.set(xticks=range(len(hands)), xticklabels=hands, ylabel="in-distribution success (%)", title=task,
               ylim=(0, 103))  # fmt: skip
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--hands", default="umi,inspire,xhand")
    parser.add_argument("--tasks", default="press_button,lift")
    parser.add_argument("--spaces", default="raw,galr")
    parser.add_argument("--epochs", default="10,30,100,300")
    parser.add_argument("--galr", default=str(packaged_path("long")))
    parser.add_argument("--work", type=Path, default=Path("outputs/learnability"))
    args = parser.parse_args()
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    setting = {"region": REGION, "demos": DEMOS, "galr": os.path.relpath(args.galr),
               "galr_sha256": galr_identity(args.galr), "commit": commit,
               "machine": f"{os.cpu_count()} cores, {platform.machine()}"}  # fmt: skip
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / "learnability.json"
    lengths = sorted(int(e) for e in args.epochs.split(","))
    for task in args.tasks.split(","):
        for hand in args.hands.split(","):
            for space in args.spaces.split(","):
                for epochs in lengths:
                    result = {**run(args.work, args.galr, hand, task, space, epochs), **setting}
                    runs = record(out, result)
                    print(json.dumps(result), flush=True)
                    plot(runs, RESULTS / "learnability.png")
                    if result["successes"] >= TARGET * result["episodes"]:
                        break


if __name__ == "__main__":
    main()
