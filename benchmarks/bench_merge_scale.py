"""`dataset merge` at a recorded dataset's size: how fast, how big, how much memory.

Three synthesised inputs as a rig's recorder lays them out (LeRobot's writer; state and action the
floating wrist + the hand's joints, one colour camera kept as AV1 video, no point clouds): umi at 30 fps
with `observation.images.front` at 96x128, Inspire at 15 fps with `observation.images.top` at 48x64, XHand
at 30 fps with `observation.images.front` at 96x128; `--frames` in all, 40/30/30 %, episodes of 150 frames.
The frames are synthetic (smooth random reaches, a moving colour gradient as the picture), not task
demonstrations: the merge reads and writes them as it would a recording. Merged with the packaged
`default` GaLR (latents cached), at the lowest rate (15 fps: the 30 fps inputs resampled), the cameras as
one role (`--camera-map front=observation.images.front front=observation.images.top`, the smaller resized),
by `lerobot-opfa dataset merge` in a subprocess with one torch thread.

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_merge_scale.py [--frames 10000,100000]
        [--work outputs/merge_scale]

Inputs are written once per size and kept under `--work`. Results: benchmarks/results/merge_scale.json, the
largest size's `{inputs: [{frames, fps, bytes, cameras, video}], output: {frames, fps, bytes, video},
seconds, frames_per_s, peak_rss_mb}` and `sizes` (the same for every size, to see memory against frames),
with the commit; merge_scale.png.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).parent))
from bench_rig import BIN, RESULTS  # noqa: E402

from lerobot_opfa.experiments.jobs import source_commit  # noqa: E402

INPUTS = (  # hand, fps, camera key, (height, width), share of the frames
    ("umi", 30, "observation.images.front", (96, 128), 0.4),
    ("inspire", 15, "observation.images.top", (48, 64), 0.3),
    ("xhand", 30, "observation.images.front", (96, 128), 0.3),
)
EPISODE = 150
ONE_THREAD = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def picture(height: int, width: int, t: int) -> np.ndarray:
    y, x = np.mgrid[0:height, 0:width]
    phase = 2 * np.pi * t / EPISODE
    rgb = np.stack([x / width, y / height, 0.5 + 0.5 * np.sin(phase + x / width)], axis=-1)
    return (255 * rgb).astype(np.uint8)


def write_input(root: Path, hand: str, fps: int, camera: str, size: tuple[int, int], frames: int) -> Path:
    """A recording of `frames` frames of `hand` at `fps`, its camera as video; written whole or not at all."""
    from lerobot.utils.constants import ACTION, OBS_STATE

    from lerobot_opfa.datasets.io import new_dataset
    from lerobot_opfa.datasets.synthetic import WRIST_NAMES
    from lerobot_opfa.hands.registry import load_hand

    if (root / "meta" / "info.json").exists():
        return root
    model = load_hand(hand)
    names = [*WRIST_NAMES, *model.joint_names]
    features = {
        OBS_STATE: {"dtype": "float32", "shape": (len(names),), "names": names},
        ACTION: {"dtype": "float32", "shape": (len(names),), "names": names},
        camera: {"dtype": "video", "shape": (*size, 3), "names": ["height", "width", "channels"]},
    }
    rng = np.random.default_rng(len(hand))
    lower, upper = model.lower.double().numpy(), model.upper.double().numpy()
    create = dict(repo_id=f"local/{root.name}", fps=fps, features=features, robot_type=hand, use_videos=True)
    with new_dataset(root, **create) as dataset, tqdm(total=frames, desc=f"writing {root.name}") as bar:
        for start in range(0, frames, EPISODE):
            length = min(EPISODE, frames - start)
            s = np.linspace(0, 1, length + 1)[:, None]
            wrist = np.zeros((length + 1, 6))
            wrist[:, :3] = (1 - s) * [0.0, 0.0, 0.3] + s * [*rng.uniform(-0.2, 0.2, 2), 0.05]
            joints = lower + (upper - lower) * rng.uniform(0.3, 0.9, len(lower)) * s
            trajectory = np.concatenate([wrist, joints], axis=1).astype(np.float32)
            for t in range(length):
                frame = {OBS_STATE: trajectory[t], ACTION: trajectory[t + 1], "task": "lift the object"}
                dataset.add_frame(frame | {camera: picture(*size, t)})
            dataset.save_episode()
            bar.update(length)
    return root


def folder_bytes(root: Path) -> int:
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file())


def info(root: Path) -> dict:
    return json.loads((root / "meta" / "info.json").read_text())


def merge_run(work: Path, frames: int) -> dict:
    inputs = [
        write_input(work / f"{frames}" / f"{hand}_{fps}fps", hand, fps, camera, size, round(share * frames))
        for hand, fps, camera, size, share in INPUTS
    ]
    output = work / f"{frames}" / "merged"
    command = [
        str(BIN / "lerobot-opfa"), "dataset", "merge", "--inputs", *map(str, inputs), "--output", str(output),
        "--galr", "default", "--overwrite", "--camera-map",
        *sorted({f"front={camera}" for _, _, camera, _, _ in INPUTS}),
    ]  # fmt: skip
    start = time.perf_counter()
    merge = subprocess.Popen(command, env=ONE_THREAD)
    _, status, usage = os.wait4(merge.pid, 0)  # this child's own peak memory
    seconds = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"dataset merge failed: {' '.join(command)}")
    written = info(output)
    cameras = [k for k, f in written["features"].items() if f["dtype"] in ("video", "image")]
    return {
        "inputs": [
            {
                "frames": info(root)["total_frames"],
                "fps": info(root)["fps"],
                "bytes": folder_bytes(root),
                "cameras": {
                    k: f["shape"] for k, f in info(root)["features"].items() if f["dtype"] == "video"
                },
                "video": any(f["dtype"] == "video" for f in info(root)["features"].values()),
            }
            for root in inputs
        ],
        "output": {
            "frames": written["total_frames"],
            "fps": written["fps"],
            "bytes": folder_bytes(output),
            "video": all(written["features"][k]["dtype"] == "video" for k in cameras),
        },
        "seconds": round(seconds, 1),
        "frames_per_s": round(sum(info(root)["total_frames"] for root in inputs) / seconds, 1),
        "peak_rss_mb": round(usage.ru_maxrss / 1024, 1),
    }


def plot(sizes: list[dict], path: Path) -> None:
    from matplotlib.figure import Figure

    figure = Figure(figsize=(9, 3.5))
    speed, memory = figure.subplots(1, 2)
    frames = [sum(i["frames"] for i in run["inputs"]) for run in sizes]
    speed.plot(frames, [run["frames_per_s"] for run in sizes], "o-", label="dataset merge")
    speed.axhline(300, color="grey", linestyle="--", label="target 300 frames/s")
    speed.set_xlabel("input frames")
    speed.set_ylabel("frames/s (2 cores, 1 torch thread)")
    speed.legend(fontsize=8)
    memory.plot(frames, [run["peak_rss_mb"] for run in sizes], "o-")
    memory.set_xlabel("input frames")
    memory.set_ylabel("peak RSS (MB)")
    for axis in (speed, memory):
        axis.set_xscale("log")
        axis.set_ylim(bottom=0)
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--frames", default="10000,100000", help="comma-separated input sizes (frames in all)"
    )
    parser.add_argument("--work", type=Path, default=Path("outputs/merge_scale"))
    args = parser.parse_args()
    sizes = []
    for frames in sorted(int(f) for f in args.frames.split(",")):
        sizes.append(merge_run(args.work.resolve(), frames))
        print(json.dumps({k: v for k, v in sizes[-1].items() if k != "inputs"}), flush=True)
    report = {**sizes[-1], "sizes": sizes, "commit": source_commit(), "machine": f"{os.cpu_count()} cores"}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "merge_scale.json").write_text(json.dumps(report, indent=2))
    plot(sizes, RESULTS / "merge_scale.png")


if __name__ == "__main__":
    main()
