"""Point clouds per second (N = 1024, B = 256) for every built-in hand on the CPU, against forward
kinematics alone (the floor: a cloud is the link poses times fixed surface samples) and a naive baseline
in the same run: a yourdfpy scene posed at each configuration and sampled with trimesh.

    .venv/bin/python benchmarks/bench_hand_clouds.py [--hands umi,leap] [--repeats 5]

Writes benchmarks/results/hand_clouds.json and hand_clouds.png.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
import trimesh  # noqa: E402
import yourdfpy  # noqa: E402

from lerobot_opfa.hands import builtin_hands, load_hand  # noqa: E402

RESULTS = Path(__file__).parent / "results"


def rates(calls: dict[str, Callable], q: torch.Tensor, repeats: int, rounds: int) -> dict[str, float]:
    """Configurations per second of each `call(q)` in its fastest of `rounds` rounds of `repeats` calls.
    The calls take turns round by round, so that a slow spell of the machine reaches all of them alike,
    and the fastest round is the least disturbed."""
    for call in calls.values():
        call(q[:2])  # FK caches, and the surface samples drawn once, as every later call reuses them
    best = dict.fromkeys(calls, float("inf"))
    for _ in range(rounds):
        for name, call in calls.items():
            start = time.perf_counter()
            for _ in range(repeats):
                call(q)
            best[name] = min(best[name], time.perf_counter() - start)
    return {name: repeats * len(q) / seconds for name, seconds in best.items()}


def naive(hand, q: torch.Tensor, n_points: int) -> float:
    robot = yourdfpy.URDF.load(str(hand.spec.model_path), build_scene_graph=True, load_meshes=True)
    names = robot.actuated_joint_names
    q_all = hand.expand(q).numpy()
    columns = [hand.chain_joint_names.index(n) for n in names]
    start = time.perf_counter()
    for values in q_all[:, columns]:
        robot.update_cfg(values)
        mesh = robot.scene.to_mesh()
        trimesh.sample.sample_surface(mesh, n_points)
    return len(q) / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hands", default="all")
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--n-points", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument(
        "--rounds", type=int, default=20, help="timed rounds of --repeats calls; the fastest counts"
    )
    parser.add_argument("--naive-configs", type=int, default=32, help="configurations timed for the baseline")
    args = parser.parse_args()
    names = list(builtin_hands()) if args.hands == "all" else args.hands.split(",")

    rows = []
    for name in names:
        hand = load_hand(name)
        q = hand.sample_joints(args.batch, torch.Generator().manual_seed(0))
        timed = {"fk": hand.forward_kinematics, "clouds": partial(hand.point_cloud, n_points=args.n_points)}
        rate = rates(timed, q, args.repeats, args.rounds)
        fk, fast = rate["fk"], rate["clouds"]
        slow = naive(hand, q[: args.naive_configs], args.n_points)
        rows.append(
            {
                "hand": name,
                "dof": hand.dof,
                "links": len(hand.link_names),
                "fk_configs_per_s": fk,
                "ours_clouds_per_s": fast,
                "clouds_vs_fk": fast / fk,
                "naive_clouds_per_s": slow,
                "speedup": fast / slow,
            }
        )
        print(
            f"{name:<16} FK {fk:9.0f} configs/s   ours {fast:9.0f} clouds/s ({fast / fk:.2f} of FK)   "
            f"naive {slow:7.1f} clouds/s   x{fast / slow:.0f}"
        )

    result = {
        "benchmark": "hand point clouds per second",
        "command": "python benchmarks/bench_hand_clouds.py",
        "settings": {
            "batch": args.batch,
            "n_points": args.n_points,
            "device": "cpu",
            "torch_threads": torch.get_num_threads(),
            "timing": f"fastest of {args.rounds} rounds of {args.repeats} calls, FK and clouds taking turns",
        },
        "machine": {
            "cpu": platform.processor() or platform.machine(),
            "python": platform.python_version(),
            "torch": torch.__version__,
        },
        "baseline": "yourdfpy scene updated per configuration + trimesh sample_surface per configuration",
        "hands": rows,
        "geomean_speedup": float(np.exp(np.mean([np.log(r["speedup"]) for r in rows]))),
        "min_clouds_vs_fk": min(r["clouds_vs_fk"] for r in rows),
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "hand_clouds.json").write_text(json.dumps(result, indent=2))

    fig, ax = plt.subplots(figsize=(10, 4.5))
    x = np.arange(len(rows))
    ax.bar(x - 0.27, [r["fk_configs_per_s"] for r in rows], 0.27, label="forward kinematics alone")
    ax.bar(x, [r["ours_clouds_per_s"] for r in rows], 0.27, label="HandModel.point_cloud (batched)")
    ax.bar(
        x + 0.27,
        [r["naive_clouds_per_s"] for r in rows],
        0.27,
        label="naive: yourdfpy scene + trimesh per pose",
    )
    ax.set_yscale("log")
    ax.set_xticks(x, [f"{r['hand']}\n{r['dof']} DoF" for r in rows], fontsize=8)
    ax.set_ylabel("clouds (or FK configurations) per second, log")
    ax.set_title(
        f"Hand clouds, N={args.n_points}, B={args.batch}, CPU ({torch.get_num_threads()} threads); "
        f"x{result['geomean_speedup']:.0f} over naive; clouds >= {result['min_clouds_vs_fk']:.2f} x FK's rate"
    )
    ax.legend()
    fig.tight_layout()
    fig.savefig(RESULTS / "hand_clouds.png", dpi=110)
    print(f"geomean speedup x{result['geomean_speedup']:.0f}; wrote {RESULTS}/hand_clouds.json and .png")


if __name__ == "__main__":
    main()
