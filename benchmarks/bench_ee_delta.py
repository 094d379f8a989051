"""A robot whose state and action hold different entries, learned as well as one whose do not.

    HF_HUB_OFFLINE=1 MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_ee_delta.py \
        [--out outputs/bench_ee_delta]

umi on `press_button` in `mid_center`, the simulator recording and evaluating under each control: `ee_delta`
(action: tool steps and a 0..1 grasp command; state: wrist joints, their velocities and a -1..1 gripper
reading, read through a joint map with `state_joints` / `action_joints`) and `joints` (the wrist pose and
the jaw in both). Per control and action space (`galr`, `raw`): 20 expert demos (seed 11), `lerobot-opfa
train` for 30 epochs at batch 32 (the learnability benchmark's settings), 50 `lerobot-eval` episodes
(seed 1000). Every step is skipped when its output exists, so the run resumes where it stopped. Results:
benchmarks/results/ee_delta.{json,png}, the JSON a list `runs` of {control, action_space, successes,
episodes, epochs, train_minutes, commit}.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

from lerobot_opfa.envs.control import EndEffectorDeltas
from lerobot_opfa.experiments.jobs import source_commit
from lerobot_opfa.hands.registry import load_hand

HAND, TASK, REGION = "umi", "press_button", "mid_center"
DEMOS, EPOCHS, BATCH, EPISODES = 20, 30, 32, 50
RESULTS = Path(__file__).parent / "results" / "ee_delta.json"
BIN = Path(sys.executable).parent


def write_map(path: Path) -> Path:
    """umi's jaw from the simulator's -1 (open) .. 1 (closed) reading and 0 (open) .. 1 (closed) command."""
    control = EndEffectorDeltas(load_hand(HAND))
    travel = control.closed - control.open
    path.write_text(
        f"hand: {HAND}\n"
        f"state_joints:\n  gripper: {{joint: left_jaw_joint, scale: {travel / 2!r}, "
        f"offset: {control.open + travel / 2!r}}}\n"
        f"action_joints:\n  grasp: {{joint: left_jaw_joint, scale: {travel!r}, offset: {control.open!r}}}\n"
    )
    return path


def run(command: list, log: Path) -> None:
    with log.open("w") as out:
        subprocess.run([str(c) for c in command], stdout=out, stderr=subprocess.STDOUT, check=True)


def cell(out: Path, control: str, space: str, joint_map: Path) -> dict:
    demos = out / f"demos_{control}"
    if not demos.exists():
        run([BIN / "lerobot-opfa", "sim", "demos", "--task", TASK, "--hand", HAND, "--regions", REGION,
             "--episodes", DEMOS, "--seed", 11, "--control", control, "--pointcloud-source", "geometry",
             "--n-points", 256, "--output-dir", demos], out / f"demos_{control}.log")  # fmt: skip
    train = out / f"train_{control}_{space}"
    if not (train / "checkpoints" / "last").exists():
        frames = json.loads((demos / "meta" / "info.json").read_text())["total_frames"]
        steps = math.ceil(frames * EPOCHS / BATCH)
        mapped = [f"--policy.joint_map={joint_map}"] if control == "ee_delta" else []
        start = time.monotonic()
        run([BIN / "lerobot-opfa", "train", "--policy.type=opfa", f"--policy.action_space={space}", *mapped,
             f"--dataset.repo_id=local/demos_{control}", f"--dataset.root={demos}", f"--batch_size={BATCH}",
             f"--steps={steps}", f"--policy.scheduler_warmup_steps={steps // 10}",
             f"--policy.scheduler_decay_steps={steps}", f"--save_freq={steps}", "--log_freq=100",
             "--policy.pointcloud_widths=[32,64,128]", "--policy.optimizer_lr=3e-4",
             "--policy.push_to_hub=false", "--wandb.enable=false", "--seed=0", f"--output_dir={train}"],
            out / f"train_{control}_{space}.log")  # fmt: skip
        (train / "train_seconds.txt").write_text(str(round(time.monotonic() - start)))
    evaluated = out / f"eval_{control}_{space}"
    if not (evaluated / "eval_info.json").exists():
        run([BIN / "lerobot-eval", f"--policy.path={train / 'checkpoints' / 'last' / 'pretrained_model'}",
             "--policy.device=cpu", "--env.type=opfa", f"--env.task={TASK}", f"--env.hand={HAND}",
             f"--env.control={control}", f"--env.regions={REGION}", "--env.obs_type=pointcloud",
             "--env.pointcloud_source=geometry", "--env.n_points=256", f"--eval.n_episodes={EPISODES}",
             "--eval.batch_size=25", "--eval.use_async_envs=false", "--seed=1000",
             f"--output_dir={evaluated}"], out / f"eval_{control}_{space}.log")  # fmt: skip
    overall = json.loads((evaluated / "eval_info.json").read_text())["overall"]
    return {
        "control": control,
        "action_space": space,
        "successes": round(overall["pc_success"] * overall["n_episodes"] / 100),
        "episodes": overall["n_episodes"],
        "epochs": EPOCHS,
        "train_minutes": round(int((train / "train_seconds.txt").read_text()) / 60, 2),
        "commit": (out / "commit.txt").read_text().strip(),
    }


def plot(runs: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.2))
    for i, space in enumerate(("galr", "raw")):
        cells = [r for r in runs if r["action_space"] == space]
        rates = [100 * r["successes"] / r["episodes"] for r in cells]
        bars = ax.bar([j + 0.38 * i for j in range(len(cells))], rates, 0.36, label=space)
        ax.bar_label(bars, [f"{r['successes']}/{r['episodes']}" for r in cells], fontsize=8)
    ax.set_xticks([0.19, 1.19], ["ee_delta\n(state 13, action 5)", "joints\n(state = action, 7)"])
    ax.set_ylabel("success (%)")
    ax.set_ylim(0, 110)
    ax.set_title(f"{HAND}, {TASK}, {REGION}: {DEMOS} demos, {EPOCHS} epochs", fontsize=9)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/bench_ee_delta"))
    out = parser.parse_args().out
    out.mkdir(parents=True, exist_ok=True)
    if not (out / "commit.txt").exists():
        (out / "commit.txt").write_text(source_commit())
    joint_map = write_map(out / "map.yaml")
    runs = [cell(out, c, s, joint_map) for c in ("ee_delta", "joints") for s in ("galr", "raw")]
    RESULTS.write_text(json.dumps({"runs": runs}, indent=2) + "\n")
    plot(runs, RESULTS.with_suffix(".png"))
    for r in runs:
        print(f"{r['control']:9s} {r['action_space']:5s} {r['successes']}/{r['episodes']}")


if __name__ == "__main__":
    main()
