"""Training throughput on the CPU: `lerobot-train` next to `lerobot-opfa train` (LeRobot's same training loop
on the dataset held in memory), on the same dataset, policy and batch size, in one run, each at its fastest
loader-worker and torch-thread setting; plus the data-loading share of a fast-path step.

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_training.py [--steps 60] [--skip 10] [--repeats 3]

Data: 20 scripted demos (umi, press_button, mid_center, 256 geometry points) recorded with
`lerobot-opfa sim demos`. Policy: opfa on raw joints with the `small` scale's flags, batch 32, seed 0 (both
commands then draw the same batches). Each run trains `--steps` steps with `--log_freq=1` and no checkpoint;
a step's time is LeRobot's own `updt_s` + `data_s` (`data_s`: waiting for the batch plus LeRobot's
preprocessor, as LeRobot times it), and samples/s is batch size x steps / their summed time over the steps
after the first `--skip` (loader start-up, allocator warm-up). Every setting runs `--repeats` times,
interleaved with the others, and keeps its best run: other processes on the machine only slow runs down.
`lerobot-opfa train` also has glibc keep freed memory for reuse (fewer page faults in the update step);
one extra, informational `lerobot-train` setting runs with the same allocator settings (glibc's
MALLOC_*_THRESHOLD_ variables), so the JSON shows how much of the speedup that part is.
Writes benchmarks/results/training.json and training.png.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402

RESULTS = Path(__file__).parent / "results"
BIN = Path(sys.executable).parent
DEMOS = ["--task", "press_button", "--regions", "mid_center", "--episodes", "20",
         "--n-points", "256", "--pointcloud-source", "geometry", "--repo-id", "local/demos"]  # fmt: skip
POLICY = ["--policy.type=opfa", "--policy.action_space=raw", "--policy.pointcloud_widths=[32,64,128]",
          "--policy.optimizer_lr=3e-4", "--batch_size=32"]  # fmt: skip
BATCH_SIZE = 32
SETTINGS = [
    *[("lerobot-train", workers, threads, False) for workers in (0, 2) for threads in (1, 2)],
    *[("lerobot-opfa train", workers, threads, False) for workers in (0, 2) for threads in (1, 2)],
    ("lerobot-train", 2, 1, True),
]
"""(command, loader workers, torch threads of the training process, glibc memory reuse set from outside:
the informational setting, not a candidate for lerobot-train's best)."""
MEMORY_REUSE = {"MALLOC_MMAP_THRESHOLD_": str(1 << 30), "MALLOC_TRIM_THRESHOLD_": str((1 << 31) - 1)}
"""What `lerobot-opfa train` sets with mallopt, as environment variables for lerobot-train."""
STEP = re.compile(r"step:(\d+) .*?updt_s:([\d.]+) data_s:([\d.]+)")


def record_demos(root: Path, hand: str = "umi") -> Path:
    if not (root / "meta" / "info.json").exists():
        command = [
            str(BIN / "lerobot-opfa"),
            "sim",
            "demos",
            "--hand",
            hand,
            *DEMOS,
            "--output-dir",
            str(root),
        ]
        subprocess.run(command, check=True, capture_output=True, env=_env(1))
    return root


PATHS = {
    "single_hand_raw": ("single", "raw"),
    "single_hand_galr": ("single", "galr"),
    "merged_galr": ("merged", "galr"),
    "merged_per_embodiment": ("merged", "per_embodiment"),
}
"""Every documented `lerobot-opfa train` path: (dataset, action space). The single-hand dataset is the umi
demos; the merged one is them and the Inspire's, merged with the GaLR (its z cached per frame)."""
GALR = "default"


def measure_paths(tmp: Path, single: Path, setting: tuple, steps: int, skip: int) -> dict:
    """samples/s and the data share of a step of each path, at the fast path's best setting."""
    from lerobot_opfa.datasets.merge import merge_datasets

    inspire = record_demos(tmp / "bench_demos_inspire", "inspire")
    merged = merge_datasets(
        [single, inspire], tmp / "bench_merged", GALR, "local/bench_merged", overwrite=True
    )
    datasets = {"single": single, "merged": merged}
    paths = {}
    for name, (dataset, space) in PATHS.items():
        policy = [*POLICY[:1], f"--policy.action_space={space}", f"--policy.galr_path={GALR}", *POLICY[2:]]
        run = train(datasets[dataset], tmp / f"path_{name}", setting, steps, skip, policy)
        paths[name] = {"samples_per_s": run["samples_per_s"], "data_fraction": run["data_share"],
                       "update_s": run["update_s"], "data_s": run["data_s"]}  # fmt: skip
        print(
            f"{name}: {run['samples_per_s']:6.1f} samples/s, data {100 * run['data_share']:.1f}%", flush=True
        )
    return paths


def _env(threads: int, memory_reuse: bool = False) -> dict[str, str]:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "MUJOCO_GL": "egl", "OMP_NUM_THREADS": str(threads)}
    return env | MEMORY_REUSE if memory_reuse else env


def train(data: Path, out: Path, setting: tuple, steps: int, skip: int, policy: list[str] = POLICY) -> dict:
    """One training run; its steady-state step times from LeRobot's per-step log."""
    command, workers, threads, memory_reuse = setting
    exe = [str(BIN / "lerobot-train")] if command == "lerobot-train" else [str(BIN / "lerobot-opfa"), "train"]
    args = [
        *policy, f"--dataset.repo_id=local/{data.name}", f"--dataset.root={data}", "--policy.device=cpu",
        "--policy.push_to_hub=false", "--wandb.enable=false", "--save_checkpoint=false", "--log_freq=1",
        f"--steps={steps}", "--seed=0", f"--num_workers={workers}", f"--output_dir={out}",
    ]  # fmt: skip
    start = time.perf_counter()
    result = subprocess.run([*exe, *args], capture_output=True, text=True, env=_env(threads, memory_reuse))
    wall = time.perf_counter() - start
    log = result.stdout + result.stderr
    if result.returncode != 0:
        raise RuntimeError(f"{command} failed (exit {result.returncode}):\n{log[-3000:]}")
    rows = [(int(s), float(u), float(d)) for s, u, d in STEP.findall(log)]
    steady = [(u, d) for s, u, d in rows if s > skip]
    if len(steady) < 5:
        raise RuntimeError(f"{command}: only {len(steady)} steady-state steps logged; raise --steps")
    update, data_s = sum(u for u, _ in steady), sum(d for _, d in steady)
    return {
        "command": command,
        "num_workers": workers,
        "torch_threads": threads,
        "memory_reuse_env": memory_reuse,
        "samples_per_s": BATCH_SIZE * len(steady) / (update + data_s),
        "step_s": (update + data_s) / len(steady),
        "update_s": update / len(steady),
        "data_s": data_s / len(steady),
        "data_share": data_s / (update + data_s),
        "steady_steps": len(steady),
        "process_wall_s": wall,
    }


def _label(run: dict) -> str:
    reuse = " + memory reuse (info)" if run["memory_reuse_env"] else ""
    return f"{run['command']}{reuse}: {run['num_workers']} workers, {run['torch_threads']} thread(s)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=60, help="training steps per run")
    parser.add_argument("--skip", type=int, default=10, help="first steps left out of the timing")
    parser.add_argument("--repeats", type=int, default=3, help="runs per setting (the best is kept)")
    parser.add_argument("--data", type=Path, help="reuse (or record once into) this demos folder")
    parser.add_argument("--note", help="stored in the JSON, e.g. what else ran on the machine")
    parser.add_argument(
        "--paths-only", action="store_true", help="measure only `paths`, at training.json's fast setting"
    )
    args = parser.parse_args()
    load_before = os.getloadavg()
    if args.paths_only:
        result = json.loads((RESULTS / "training.json").read_text())
        fast = result["fast_setting"]
        setting = ("lerobot-opfa train", fast["num_workers"], fast["torch_threads"], False)
        with tempfile.TemporaryDirectory() as tmp:
            single = record_demos(args.data or Path(tmp) / "bench_demos")
            result["paths"] = measure_paths(Path(tmp), single, setting, args.steps, args.skip)
        result["paths_run"] = {"steps": args.steps, "skip": args.skip, "galr": GALR, "note": args.note,
                               "load_average_1_5_15_min_before": load_before,
                               "load_average_1_5_15_min_after": os.getloadavg()}  # fmt: skip
        (RESULTS / "training.json").write_text(json.dumps(result, indent=2))
        plot_paths(result["paths"])
        return
    with tempfile.TemporaryDirectory() as tmp:
        data = record_demos(args.data or Path(tmp) / "bench_demos")
        frames = json.loads((data / "meta" / "info.json").read_text())["total_frames"]
        runs = []
        for repeat in range(args.repeats):
            for i, setting in enumerate(SETTINGS):
                run = train(data, Path(tmp) / f"run{repeat}_{i}", setting, args.steps, args.skip)
                runs.append(run)
                print(
                    f"{_label(run)}: {run['samples_per_s']:6.1f} samples/s (update {run['update_s']:.3f} s, "
                    f"data {run['data_s']:.3f} s per step)",
                    flush=True,
                )
        best = {}
        for run in runs:
            key = _label(run)
            if key not in best or run["samples_per_s"] > best[key]["samples_per_s"]:
                best[key] = run
        settings = list(best.values())
        candidates = [r for r in settings if not r["memory_reuse_env"]]
        fast = max(
            (r for r in candidates if r["command"] != "lerobot-train"), key=lambda r: r["samples_per_s"]
        )
        setting = (fast["command"], fast["num_workers"], fast["torch_threads"], False)
        paths = measure_paths(Path(tmp), data, setting, args.steps, args.skip)
    best = {}
    for run in runs:
        key = _label(run)
        if key not in best or run["samples_per_s"] > best[key]["samples_per_s"]:
            best[key] = run
    settings = list(best.values())
    candidates = [r for r in settings if not r["memory_reuse_env"]]
    stock = max((r for r in candidates if r["command"] == "lerobot-train"), key=lambda r: r["samples_per_s"])
    fast = max((r for r in candidates if r["command"] != "lerobot-train"), key=lambda r: r["samples_per_s"])
    reuse = next(r for r in settings if r["memory_reuse_env"])
    result = {
        "benchmark": "training samples/s: lerobot-train vs lerobot-opfa train (dataset held in memory)",
        "command": "python benchmarks/bench_training.py"
        + f" --steps {args.steps} --skip {args.skip} --repeats {args.repeats}",
        "lerobot_train_samples_per_s": stock["samples_per_s"],
        "fast_samples_per_s": fast["samples_per_s"],
        "speedup": fast["samples_per_s"] / stock["samples_per_s"],
        "fast_data_share": fast["data_share"],
        "lerobot_train_data_share": stock["data_share"],
        "lerobot_train_setting": {
            "num_workers": stock["num_workers"],
            "torch_threads": stock["torch_threads"],
        },
        "fast_setting": {"num_workers": fast["num_workers"], "torch_threads": fast["torch_threads"]},
        "lerobot_train_with_memory_reuse_samples_per_s": reuse["samples_per_s"],  # informational
        "targets": {"speedup": 2.5, "fast_data_share": 0.05},
        "settings": {
            "dataset": f"lerobot-opfa sim demos --hand umi {' '.join(DEMOS)}",
            "frames": frames,
            "policy_flags": POLICY,
            "steps_per_run": args.steps,
            "skipped_steps": args.skip,
            "repeats": args.repeats,
        },
        "machine": {
            "cpu": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
            "python": platform.python_version(),
            "torch": torch.__version__,
            "load_average_1_5_15_min_before": load_before,  # other processes compete for the cores
            "load_average_1_5_15_min_after": os.getloadavg(),
        },
        "note": args.note,
        "paths": paths,
        "paths_run": {"steps": args.steps, "skip": args.skip, "galr": GALR, "note": args.note},
        "best_run_per_setting": settings,
        "all_runs": runs,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "training.json").write_text(json.dumps(result, indent=2))
    print(
        f"lerobot-train {stock['samples_per_s']:.1f} samples/s, fast path {fast['samples_per_s']:.1f} "
        f"({result['speedup']:.2f}x), data loading {100 * fast['data_share']:.1f}% of a fast step"
    )
    plot(settings, stock, fast, result["speedup"])
    plot_paths(paths)
    print(f"wrote {RESULTS}/training.json and .png")


def plot(settings: list[dict], stock: dict, fast: dict, speedup: float) -> None:
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [3, 2]})
    labels = [_label(r).replace(": ", "\n") for r in settings]
    colors = [
        "C7" if r["memory_reuse_env"] else "C0" if r["command"] == "lerobot-train" else "C1" for r in settings
    ]
    bars = left.barh(labels, [r["samples_per_s"] for r in settings], color=colors)
    for bar, run in zip(bars, settings, strict=True):
        bold = run is stock or run is fast
        left.text(bar.get_width(), bar.get_y() + bar.get_height() / 2, f" {run['samples_per_s']:.0f}",
                  va="center", fontsize=8, fontweight="bold" if bold else "normal")  # fmt: skip
    left.set_xlabel(f"training samples per second (batch {BATCH_SIZE}, steady state)")
    left.invert_yaxis()
    left.tick_params(axis="y", labelsize=8)
    names = ["lerobot-train (best)", "lerobot-opfa train (best)"]
    update = [stock["update_s"] * 1000, fast["update_s"] * 1000]
    data = [stock["data_s"] * 1000, fast["data_s"] * 1000]
    right.bar(names, update, color="C2", label="update (updt_s)")
    right.bar(names, data, bottom=update, color="C3", label="data loading + preprocessor (data_s)")
    right.set_ylabel("ms per step")
    right.set_title(
        f"{speedup:.2f}x samples/s; data {100 * fast['data_share']:.1f}% of a fast step", fontsize=10
    )
    right.legend(fontsize=8)
    fig.suptitle(f"opfa training on {os.cpu_count()} CPU cores: lerobot-train vs the in-memory fast path")
    fig.tight_layout()
    fig.savefig(RESULTS / "training.png", dpi=110)


def plot_paths(paths: dict) -> None:
    fig, ax = plt.subplots(figsize=(7, 3.5))
    names = list(paths)
    bars = ax.barh(names, [paths[n]["samples_per_s"] for n in names], color="C1")
    for bar, name in zip(bars, names, strict=True):
        ax.text(bar.get_width(), bar.get_y() + bar.get_height() / 2,
                f" {paths[name]['samples_per_s']:.0f} ({100 * paths[name]['data_fraction']:.1f}% data)",
                va="center", fontsize=8)  # fmt: skip
    ax.set_xlabel(f"lerobot-opfa train samples per second (batch {BATCH_SIZE})")
    ax.invert_yaxis()
    ax.set_title(
        "every documented training path: samples/s and the share of a step spent on data", fontsize=10
    )
    fig.tight_layout()
    fig.savefig(RESULTS / "training_paths.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
