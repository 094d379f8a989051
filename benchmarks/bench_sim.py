"""The MuJoCo benchmark: env steps per second (no point cloud, geometry-sampled, depth cameras) and
scripted-expert success rate for every (task, hand) pair over seeded episodes.

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_sim.py [--episodes 50] [--hands all] [--tasks all]

Speed is steps per CPU-second of the process (all its threads, renderer included): on a shared machine
wall-clock rates measure the neighbours, CPU time measures the env; on an idle core the two agree (the
JSON keeps both). Results are written after every measurement, and `--resume` skips what the JSON already
holds, so a long run can be stopped and continued. Writes benchmarks/results/sim.json and sim.png.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from lerobot_opfa.envs.env import OpfaSimEnv  # noqa: E402
from lerobot_opfa.envs.experts import EXCLUDED_PAIRS, ScriptedExpert  # noqa: E402
from lerobot_opfa.envs.tasks import ONE_HAND_TASKS, TASKS  # noqa: E402
from lerobot_opfa.hands import builtin_hands  # noqa: E402

RESULTS = Path(__file__).parent / "results"
SPEED_MODES = {"no point cloud": ("state", "depth"), "geometry cloud": ("pointcloud", "geometry"),
               "depth cloud": ("pointcloud", "depth")}  # fmt: skip
TARGET_SUCCESS, TARGET_STEPS_PER_S = 0.9, 200.0


def steps_per_second(task: str, hand: str, obs_type: str, source: str, n_points: int, steps: int) -> dict:
    """Expert-driven steps (contacts included), timed without resets, observations computed every step."""
    env = OpfaSimEnv(task, hand, obs_type=obs_type, pointcloud_source=source, n_points=n_points)
    env.reset(seed=0)
    env.step(env.observation()["agent_pos"])  # builds the renderers and caches outside the timing
    timed, cpu, wall, seed = 0, 0.0, 0.0, 0
    while timed < steps:
        env.reset(seed=seed)
        expert, done = ScriptedExpert(env, np.random.default_rng(seed)), False
        cpu0, wall0 = time.process_time(), time.perf_counter()
        while not (done or expert.done) and timed < steps:
            _, _, done, _, _ = env.step(expert.act())
            timed += 1
        cpu += time.process_time() - cpu0
        wall += time.perf_counter() - wall0
        seed += 1
    env.close()
    return {"cpu": timed / cpu, "wall": timed / wall}


def success_rate(task: str, hand: str, episodes: int) -> dict:
    """Fraction of seeded expert episodes (seeds 0..episodes-1, regions drawn from all nine) that succeed,
    by the env's own test of the simulator state, and the mean length of the successful ones."""
    env = OpfaSimEnv(task, hand, obs_type="state")
    lengths = []
    for seed in range(episodes):
        env.reset(seed=seed)
        expert = ScriptedExpert(env, np.random.default_rng(seed))
        for step in range(TASKS[task].episode_steps):
            if env.step(expert.act())[2]:
                lengths.append(step + 1)
                break
    env.close()
    return {
        "task": task,
        "hand": hand,
        "episodes": episodes,
        "success": len(lengths) / episodes,
        "mean_steps": float(np.mean(lengths)) if lengths else None,
        "excluded": EXCLUDED_PAIRS.get((task, hand)),
    }


def summary(result: dict) -> dict:
    included = [r for r in result["success"] if not r["excluded"]]
    depth = [r["depth cloud"]["cpu"] for r in result["speed_steps_per_s"]]
    return {
        "pairs_measured": len(result["success"]),
        "min_success_non_excluded": min((r["success"] for r in included), default=None),
        "pairs_below_target": [f"{r['task']}/{r['hand']}" for r in included if r["success"] < TARGET_SUCCESS],
        "depth_steps_per_cpu_s_min": min(depth, default=None),
        "depth_steps_per_cpu_s_median": float(np.median(depth)) if depth else None,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hands", default="all")
    parser.add_argument("--tasks", default="all")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--speed-steps", type=int, default=1000)
    parser.add_argument("--speed-task", default="lift")
    parser.add_argument("--n-points", type=int, default=1024)
    parser.add_argument(
        "--resume", action="store_true", help="keep the measurements in sim.json (exclusions are refreshed)"
    )
    args = parser.parse_args()
    hands = list(builtin_hands()) if args.hands == "all" else args.hands.split(",")
    tasks = ONE_HAND_TASKS if args.tasks == "all" else args.tasks.split(",")
    path = RESULTS / "sim.json"
    old = json.loads(path.read_text()) if args.resume and path.is_file() else {}
    result = {
        "benchmark": "MuJoCo cross-embodiment benchmark: env speed and scripted-expert success",
        "command": f"MUJOCO_GL=egl python benchmarks/bench_sim.py --episodes {args.episodes} "
        f"--speed-steps {args.speed_steps}",
        "settings": {
            "episodes_per_pair": args.episodes,
            "speed_task": args.speed_task,
            "speed_steps_per_mode": args.speed_steps,
            "speed_unit": "env steps per CPU-second of the process (cpu) and per wall-clock second (wall)",
            "n_points": args.n_points,
            "control_hz": 20,
            "physics_dt_s": 0.002,
            "depth_cameras": "front only, 128x96, MUJOCO_GL=" + os.environ.get("MUJOCO_GL", ""),
            "success_obs_type": "state (success does not depend on the observation)",
        },
        "machine": {
            "cpu": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
            "python": platform.python_version(),
            "mujoco": mujoco.__version__,
        },
        "speed_steps_per_s": [r for r in old.get("speed_steps_per_s", []) if r["hand"] in hands],
        "success": [
            {**r, "excluded": EXCLUDED_PAIRS.get((r["task"], r["hand"]))}
            for r in old.get("success", [])
            if r["episodes"] == args.episodes
        ],
        "excluded_pairs": [{"task": t, "hand": h, "reason": why} for (t, h), why in EXCLUDED_PAIRS.items()],
    }

    def save() -> None:
        result["summary"] = summary(result)
        RESULTS.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result, indent=2))

    done_speed = {r["hand"] for r in result["speed_steps_per_s"]}
    for hand in tqdm([h for h in hands if h not in done_speed], desc="steps/s"):
        row = {"hand": hand}
        for mode, (obs_type, source) in SPEED_MODES.items():
            row[mode] = steps_per_second(
                args.speed_task, hand, obs_type, source, args.n_points, args.speed_steps
            )
        result["speed_steps_per_s"].append(row)
        save()
        tqdm.write("  ".join([f"{hand:<16}"] + [f"{m} {row[m]['cpu']:6.0f}/cpu-s" for m in SPEED_MODES]))

    done_pairs = {(r["task"], r["hand"]) for r in result["success"]}
    pairs = [(t, h) for t in tasks for h in hands if (t, h) not in done_pairs]
    for task, hand in tqdm(pairs, desc="expert success"):
        row = success_rate(task, hand, args.episodes)
        result["success"].append(row)
        save()
        tqdm.write(f"{task:<13} {hand:<16} {row['success']:6.1%}")

    save()
    plot(result, args)
    print(json.dumps(result["summary"], indent=2))


def plot(result: dict, args: argparse.Namespace) -> None:
    speed, success = result["speed_steps_per_s"], result["success"]
    hands = list(dict.fromkeys([r["hand"] for r in speed] + [r["hand"] for r in success]))
    tasks = list(dict.fromkeys(r["task"] for r in success))
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(11, 8), gridspec_kw={"height_ratios": [1.1, 1]})
    rates = {(r["task"], r["hand"]): r["success"] for r in success}
    grid = np.array([[rates.get((t, h), np.nan) for h in hands] for t in tasks])
    image = ax1.imshow(grid * 100, cmap="RdYlGn", vmin=0, vmax=100, aspect="auto")
    for i, task in enumerate(tasks):
        for j, hand in enumerate(hands):
            label = "n/a" if np.isnan(grid[i, j]) else f"{grid[i, j]:.0%}"
            label += "\nexcl." if (task, hand) in EXCLUDED_PAIRS else ""
            ax1.text(j, i, label, ha="center", va="center", fontsize=8)
    ax1.set_xticks(range(len(hands)), hands, fontsize=8, rotation=20)
    ax1.set_yticks(range(len(tasks)), tasks)
    ax1.set_title(f"Scripted-expert success over {args.episodes} seeded episodes per pair (target 90%)")
    fig.colorbar(image, ax=ax1, label="success %")
    x = np.arange(len(speed))
    for k, mode in enumerate(SPEED_MODES):
        ax2.bar(x + (k - 1) * 0.27, [r[mode]["cpu"] for r in speed], 0.27, label=mode)
    ax2.axhline(
        TARGET_STEPS_PER_S, color="k", ls="--", lw=1, label=f"target {TARGET_STEPS_PER_S:.0f}/s (depth)"
    )
    ax2.set_xticks(x, [r["hand"] for r in speed], fontsize=8, rotation=20)
    ax2.set_ylabel("env steps per CPU-second")
    ax2.set_title(f"Env speed, one env, task '{args.speed_task}', expert actions, N={args.n_points} points")
    ax2.legend(fontsize=8, ncol=4)
    fig.tight_layout()
    fig.savefig(RESULTS / "sim.png", dpi=110)


if __name__ == "__main__":
    main()
