"""LeRobot's own ACT in GaLR space, measured on CPU: does a stock policy co-trained on two hands' latents
succeed on each hand, and does a control that cannot (the same policy untrained) not?

Per hand (umi, Inspire), `--demos` episodes of `lift` recorded by the expert teleoperator on the `opfa_sim`
rig with `lerobot-record` (colour camera `front` at `--size`, failed episodes dropped); the hands merged
with the GaLR (`dataset merge --galr`) and turned into a latent dataset (`policy latent-dataset`: state and
action = normalised wrist + z, the colour camera kept, depth dropped). Rows (`--rows`):

- `cotrained`: one ACT trained on the latent dataset for `--epochs` (`lerobot-opfa train`), given joint
  I/O (`policy convert-io`) and run by `lerobot-eval --env.type=opfa` on each hand (`--episodes`).
- `untrained`: the control, the same configuration with its learning rates at 0 for one step (its
  weights as initialised, its normalisation the dataset's), run the same way.
- `blind`: the control that cannot see the can: the same demos recorded with the task's objects drawn by
  no camera (`--robot.hide_object`; the expert still reads where the can is), merged, trained and converted
  as `cotrained`, and evaluated in the same blind scene (`--env.hide_object`).
- `alone`: one ACT per hand trained on that hand's own joints (its recorded dataset without the depth
  camera, no GaLR).

ACT at the small size the CPU protocol allows (the exact config is written to the JSON): dim_model 256,
feedforward 1024, 2 encoder layers, chunk 20, no pretrained backbone, batch 32, learning rate 1e-4 for the
model and the backbone (LeRobot's 1e-5 suits a pretrained backbone over ~100k steps). One torch thread.

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_stock_policies.py [--rows cotrained,untrained,blind,alone]
        [--demos 20] [--epochs 40] [--episodes 50] [--work outputs/stock]

Each stage's output and wall time are kept under `--work` with the commit (`bench_rig.Stages`): an
interrupted run resumes at the stage it stopped in, and a finished cell is not run again. Results:
benchmarks/results/stock_policies.json (`runs` of {policy, action_space, hand, task, demos, successes,
episodes, epochs, train_minutes, control, follows_object, following_episodes, outcomes, commit}) and
stock_policies.png; the rows run replace their own runs in it and leave the other rows' (each run names
the commit it was trained at). `follows_object` and `outcomes` (`failures.object_following`, 20 more
episodes per cell): whether the wrist goes where the can is, and whether a failure ever touched it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from bench_rig import BIN, FPS, REGION, Stages, episodes_log, rig_args, success_bars  # noqa: E402

from lerobot_opfa.experiments.jobs import source_commit  # noqa: E402

RESULTS = Path(__file__).parent / "results"
TASK = "lift"
EVAL_SEED = 1000
FOLLOWING_EPISODES = 20
RECORD_S = 6.0
ONE_THREAD = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
ACT = [
    "--policy.type=act", "--policy.dim_model=256", "--policy.dim_feedforward=1024",
    "--policy.n_encoder_layers=2", "--policy.chunk_size=20", "--policy.n_action_steps=20",
    "--policy.pretrained_backbone_weights=null", "--policy.device=cpu", "--policy.push_to_hub=false",
]  # fmt: skip
LEARNING_RATE = 1e-4
BATCH = 32


def record(stages: Stages, hand: str, demos: int, size: int, blind: bool = False) -> Path:
    """The expert's colour demos of `hand` on the rig, failed episodes dropped (`blind`: the can drawn by no
    camera)."""
    name = f"{hand}_blind" if blind else hand
    work, calibration = stages.work, stages.work / f"rig_{name}"
    recorded, kept = work / "data" / f"{name}_recorded", work / "data" / name
    command = [
        str(BIN / "lerobot-record"), *rig_args(TASK, hand, calibration, RECORD_S, 0),
        f"--robot.width={size}", f"--robot.height={size}", "--teleop.type=opfa_expert",
        f"--dataset.repo_id=local/{name}_rig", f"--dataset.root={recorded}",
        f"--dataset.num_episodes={demos}", f"--dataset.fps={FPS}", f"--robot.hide_object={blind}",
    ]  # fmt: skip
    stages.run(f"record_{name}", [recorded, calibration], command)
    failed = [o["episode"] for o in episodes_log(calibration) if not o["success"]]
    if not failed:
        return recorded
    drop = [
        str(BIN / "lerobot-edit-dataset"), f"--repo_id=local/{name}_rig", f"--root={recorded}",
        f"--new_repo_id=local/{name}", f"--new_root={kept}", "--operation.type=delete_episodes",
        f"--operation.episode_indices={failed}",
    ]  # fmt: skip
    stages.run(f"drop_{name}", [kept], drop)
    return kept


def colour_only(stages: Stages, hand: str, data: Path) -> Path:
    """`hand`'s demos without the depth camera, which ACT would read as a one-channel picture (the latent
    dataset drops it the same way)."""
    out = stages.work / "data" / f"{hand}_colour"
    command = [
        str(BIN / "lerobot-edit-dataset"), f"--repo_id=local/{data.name}", f"--root={data}",
        f"--new_repo_id=local/{out.name}", f"--new_root={out}", "--operation.type=remove_feature",
        "--operation.feature_names=['observation.images.front_depth']",
    ]  # fmt: skip
    stages.run(f"colour_{hand}", [out], command)
    return out


def frames_of(root: Path) -> int:
    return json.loads((root / "meta" / "info.json").read_text())["total_frames"]


def episodes_of(root: Path) -> int:
    return json.loads((root / "meta" / "info.json").read_text())["total_episodes"]


def train(
    stages: Stages, name: str, dataset: Path, epochs: int, learning_rate: float, steps: int = 0
) -> Path:
    """An ACT trained on `dataset` for `epochs` (or exactly `steps`); its last checkpoint."""
    steps = steps or math.ceil(epochs * frames_of(dataset) / BATCH)
    out = stages.work / f"train_{name}"
    command = [
        str(BIN / "lerobot-opfa"), "train", *ACT, f"--policy.optimizer_lr={learning_rate}",
        f"--policy.optimizer_lr_backbone={learning_rate}", f"--dataset.repo_id=local/{dataset.name}",
        f"--dataset.root={dataset}", f"--batch_size={BATCH}", f"--steps={steps}", f"--save_freq={steps}",
        f"--log_freq={max(1, steps // 20)}", f"--output_dir={out}", "--wandb.enable=false", "--seed=0",
        "--num_workers=0",
    ]  # fmt: skip
    stages.run(f"train_{name}", [out], command, env=ONE_THREAD)
    return out / "checkpoints" / "last" / "pretrained_model"


def evaluate(
    stages: Stages, name: str, hand: str, model: Path, episodes: int, size: int, blind: bool = False
) -> tuple[int, int]:
    out = stages.work / f"eval_{name}_{hand}"
    command = [
        str(BIN / "lerobot-eval"), f"--policy.path={model}", "--policy.device=cpu", "--env.type=opfa",
        f"--env.task={TASK}", f"--env.hand={hand}", f"--env.regions={REGION}", "--env.obs_type=rgb",
        f"--env.camera_width={size}", f"--env.camera_height={size}", f"--eval.n_episodes={episodes}",
        "--eval.batch_size=1", f"--seed={EVAL_SEED}", f"--output_dir={out}", f"--env.hide_object={blind}",
    ]  # fmt: skip
    stages.run(f"eval_{name}_{hand}", [out], command, env=ONE_THREAD)
    overall = json.loads((out / "eval_info.json").read_text())["overall"]
    return round(overall["pc_success"] * overall["n_episodes"] / 100), overall["n_episodes"]


def following(stages: Stages, name: str, model: Path, hand: str, size: int, blind: bool) -> dict:
    """`failures.object_following` of a checkpoint over FOLLOWING_EPISODES episodes (one torch thread): a
    policy that reads the camera takes its wrist where the can is (slope about 1), one that does not
    goes to the same place wherever the can stands (about 0)."""
    import torch

    from lerobot_opfa.envs.config import OpfaEnvConfig
    from lerobot_opfa.experiments.failures import object_following

    config = OpfaEnvConfig(
        task=TASK, hand=hand, regions=REGION, obs_type="rgb", camera_width=size, camera_height=size,
        hide_object=blind,
    )  # fmt: skip

    def measure() -> dict:
        torch.set_num_threads(1)
        return object_following(model, config, FOLLOWING_EPISODES, EVAL_SEED)

    return stages.measure(f"following_{name}", measure)


def convert(stages: Stages, name: str, model: Path, latent: Path) -> Path:
    out = stages.work / f"joints_{name}"
    command = [str(BIN / "lerobot-opfa"), "policy", "convert-io", "--policy", str(model), "--dataset",
               str(latent), "--output", str(out)]  # fmt: skip
    stages.run(f"convert_{name}", [out], command)
    return out


def with_other_rows(kept: dict, runs: list[dict]) -> list[dict]:
    """`runs` after the runs of the results `kept` that they do not redo (a cell is its action space,
    control and hand), each of those naming its commit (the file's where it does not)."""
    ran = {(r["action_space"], r["control"], r["hand"]) for r in runs}
    others = [r for r in kept["runs"] if (r["action_space"], r["control"], r["hand"]) not in ran]
    return [{"commit": kept.get("commit"), **r} for r in others] + runs


def plot(runs: list[dict], path: Path) -> None:
    from matplotlib.figure import Figure

    figure = Figure(figsize=(7, 4))
    ax = figure.subplots()
    hands = sorted({r["hand"] for r in runs})
    rows = list(dict.fromkeys((r["action_space"], r["control"]) for r in runs))
    width = 0.8 / max(1, len(rows))
    for k, (space, control) in enumerate(rows):
        counts = []
        for hand in hands:
            cell = [r for r in runs if (r["action_space"], r["control"], r["hand"]) == (space, control, hand)]
            counts.append(
                (sum(r["successes"] for r in cell), sum(r["episodes"] for r in cell)) if cell else (0, 1)
            )
        label = f"ACT, {space}" + ("" if control == "none" else f" ({control})")
        success_bars(
            ax, [i + (k - (len(rows) - 1) / 2) * width for i in range(len(hands))], counts, width, label
        )
    ax.set_xticks(range(len(hands)), hands)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel(f"{TASK} success ({REGION}, 95 % Wilson)")
    ax.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--rows", default="cotrained,untrained,blind,alone", help="comma-separated rows")
    parser.add_argument("--hands", default="umi,inspire")
    parser.add_argument("--demos", type=int, default=20)
    parser.add_argument("--epochs", type=int, default=40)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--size", type=int, default=64, help="the colour camera's width and height")
    parser.add_argument("--galr", default="default")
    parser.add_argument("--work", type=Path, default=Path("outputs/stock"))
    args = parser.parse_args()
    stages = Stages(args.work.resolve())
    hands, rows = args.hands.split(","), args.rows.split(",")
    runs = []

    def latent_of(data: dict[str, Path], name: str) -> Path:
        """The hands' demos merged with the GaLR and turned into the latent dataset ACT trains on."""
        merged, latent = stages.work / "data" / f"merged{name}", stages.work / "data" / f"latent{name}"
        merge = [str(BIN / "lerobot-opfa"), "dataset", "merge", "--inputs", *map(str, data.values()),
                 "--output", str(merged), "--galr", args.galr]  # fmt: skip
        stages.run(f"merge{name}", [merged], merge)
        to_latent = [str(BIN / "lerobot-opfa"), "policy", "latent-dataset", "--input", str(merged),
                     "--output", str(latent), "--drop", "observation.images.front_depth"]  # fmt: skip
        stages.run(f"latent{name}", [latent], to_latent)
        return latent

    def cell(row: str, model: Path, hand: str, space: str, control: str, epochs: float, train_stage: str):
        successes, episodes = evaluate(stages, row, hand, model, args.episodes, args.size, control == "blind")
        follows = following(stages, f"{row}_{hand}", model, hand, args.size, control == "blind")
        minutes = round(stages.done[train_stage]["wall_s"] / 60, 1)
        runs.append({"policy": "act", "action_space": space, "hand": hand, "task": TASK, "demos": args.demos,
                     "successes": successes, "episodes": episodes, "epochs": epochs,
                     "train_minutes": minutes, "control": control, **follows,
                     "commit": stages.done[train_stage]["commit"]})  # fmt: skip

    data = {}
    if {"cotrained", "untrained", "alone"} & set(rows):
        data = {hand: record(stages, hand, args.demos, args.size) for hand in hands}
    if {"cotrained", "untrained"} & set(rows):
        latent = latent_of(data, "")
    if "cotrained" in rows:
        model = convert(
            stages, "cotrained", train(stages, "cotrained", latent, args.epochs, LEARNING_RATE), latent
        )
        for hand in hands:
            cell("cotrained", model, hand, "galr", "none", args.epochs, "train_cotrained")
    if "untrained" in rows:
        model = convert(stages, "untrained", train(stages, "untrained", latent, 0, 0.0, steps=1), latent)
        for hand in hands:
            cell("untrained", model, hand, "galr", "untrained", 0, "train_untrained")
    if "blind" in rows:
        blind = latent_of(
            {hand: record(stages, hand, args.demos, args.size, blind=True) for hand in hands}, "_blind"
        )
        model = convert(stages, "blind", train(stages, "blind", blind, args.epochs, LEARNING_RATE), blind)
        for hand in hands:
            cell("blind", model, hand, "galr", "blind", args.epochs, "train_blind")
    if "alone" in rows:
        for hand in hands:
            model = train(
                stages, f"alone_{hand}", colour_only(stages, hand, data[hand]), args.epochs, LEARNING_RATE
            )
            cell(f"alone_{hand}", model, hand, "joints", "none", args.epochs, f"train_alone_{hand}")
    results = RESULTS / "stock_policies.json"
    kept = json.loads(results.read_text()) if results.exists() else {"runs": []}
    runs = with_other_rows(kept, runs)
    demos_kept = {h: episodes_of(d) for h, d in data.items()}
    report = {
        "runs": runs,
        "config": {"act": ACT, "learning_rate": LEARNING_RATE, "batch_size": BATCH, "camera": f"front colour "
                   f"{args.size}x{args.size}", "region": REGION, "galr": args.galr, "torch_threads": 1,
                   "demos_recorded_per_hand": args.demos,
                   "demos_kept": demos_kept or kept.get("config", {}).get("demos_kept")},
        "commit": source_commit(),
        "stages": {**kept.get("stages", {}), **stages.done},
        "machine": f"{os.cpu_count()} cores",
    }  # fmt: skip
    RESULTS.mkdir(parents=True, exist_ok=True)
    results.write_text(json.dumps(report, indent=2))
    plot(runs, RESULTS / "stock_policies.png")
    print(json.dumps(runs, indent=2))


if __name__ == "__main__":
    main()
