"""The steps every experiment is made of, each idempotent: record demos, merge them, train a policy with
`lerobot-opfa train` (LeRobot's training loop on the dataset held in memory), evaluate it with
`lerobot-eval`. Every step writes its result under a name derived from its inputs and appears whole or not
at all, so an interrupted experiment resumes by running again: what is finished is found and skipped.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from lerobot_opfa.datasets.io import atomic_directory
from lerobot_opfa.envs import DEFAULT_FPS
from lerobot_opfa.envs.regions import REGIONS
from lerobot_opfa.experiments.scales import Scale
from lerobot_opfa.galr import checkpoints

CONDITIONS = {"wo_cotrain": "raw", "naive_cotrain": "per_embodiment", "opfa": "galr", "untrained": "galr"}
"""The paper's three conditions and the control -> the policy's `action_space`. The control, `untrained`,
is OPFA's policy on the same demos as initialised (one step at learning rate 0: its weights untouched, its
normalisation the dataset's): what a task gives a policy that has learnt nothing, which flailing within the
demos' range can score on."""
CONTROLS = ("untrained",)
CONDITION_LABELS = {
    "wo_cotrain": "w/o co-training",
    "naive_cotrain": "naive co-training",
    "opfa": "OPFA",
    "untrained": "control: OPFA untrained",
}
EVAL_SEED = 100_000
"""Evaluation episodes are seeded from here, far from the demonstrations' seeds (0 and up)."""


@dataclass(frozen=True)
class Demos:
    task: str
    hand: str
    regions: tuple[str, ...]
    episodes: int
    seed: int = 0
    arm: str | None = None
    """The arm the hand is on (None: the floating wrist)."""
    fps: int = DEFAULT_FPS

    @property
    def name(self) -> str:
        robot = robot_tag(self.hand, self.arm, self.fps)
        return f"{self.task}-{robot}-{regions_tag(self.regions)}-{self.episodes}ep-s{self.seed}"

    @property
    def covered(self) -> tuple[str, ...]:
        """The regions the episodes reach: they take the regions in turn, so fewer episodes than regions
        leave the rest without a demo."""
        return self.regions[: self.episodes]


@dataclass(frozen=True)
class Training:
    condition: str
    demos: tuple[Demos, ...]
    seed: int = 0

    def __post_init__(self):
        if self.condition not in CONDITIONS:
            raise ValueError(f"unknown condition '{self.condition}'; valid: {', '.join(CONDITIONS)}")
        if self.condition == "wo_cotrain" and len(self.demos) != 1:
            raise ValueError("w/o co-training trains on one embodiment's demos")

    @property
    def name(self) -> str:
        return f"{self.condition}-{_short_hash([d.name for d in self.demos])}-s{self.seed}"


@dataclass(frozen=True)
class Evaluation:
    training: Training
    task: str
    hand: str
    regions: tuple[str, ...]
    arm: str | None = None
    fps: int = DEFAULT_FPS

    @property
    def name(self) -> str:
        robot = robot_tag(self.hand, self.arm, self.fps)
        return f"{self.training.name}-{self.task}-{robot}-{regions_tag(self.regions)}"


def robot_tag(hand: str, arm: str | None, fps: int) -> str:
    """A robot as part of a file name: its hand, then its arm and rate where they are not the default."""
    return "-".join([hand, *([arm] if arm else []), *([f"{fps}fps"] if fps != DEFAULT_FPS else [])])


def regions_tag(regions: tuple[str, ...]) -> str:
    """Regions as part of a file name: 'all' for the whole table."""
    return "all" if set(regions) == set(REGIONS) else "+".join(regions)


def _short_hash(parts: list[str]) -> str:
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:10]


class Workspace:
    """One experiment's folder: demos/, merged/, train/, eval/ and logs/, shared by all its cells."""

    def __init__(self, root: Path, scale: Scale, galr: str, threads: int | None = None):
        """`threads`: torch threads of each training and evaluation (None: their own choice)."""
        self.root, self.scale, self.galr = Path(root), scale, checkpoints.resolve(galr)
        self._check_settings()
        self.env = {**os.environ, "HF_HUB_OFFLINE": os.environ.get("HF_HUB_OFFLINE", "1")}
        self.env.setdefault("MUJOCO_GL", "egl")
        if threads is not None:
            self.env["OMP_NUM_THREADS"] = str(threads)

    def _check_settings(self) -> None:
        """Cell names encode neither the scale nor the GaLR checkpoint, so a folder made with others (or
        with a scale whose definition has changed since) would resume with stale latents and policies:
        refuse it."""
        recorded = self.root / "settings.json"
        scale = {f"scale.{k}": v for k, v in asdict(self.scale).items()}
        current = json.loads(json.dumps({**scale, "galr": galr_identity(self.galr)}))
        if recorded.exists():
            previous = json.loads(recorded.read_text())
            changed = sorted(k for k in current.keys() | previous.keys() if current.get(k) != previous.get(k))
            if changed:
                raise ValueError(
                    f"{self.root} was made with other settings ({', '.join(changed)} differ); "
                    "use a new --output-dir or remove the folder"
                )
        elif self.root.exists() and any(self.root.iterdir()):
            raise ValueError(
                f"{self.root} holds results but no settings.json (made by an older version, with settings "
                "that cannot be checked); use a new --output-dir or remove the folder"
            )
        else:
            self.root.mkdir(parents=True, exist_ok=True)
            recorded.write_text(json.dumps(current, indent=2))

    # --- demonstrations ---------------------------------------------------------------------------
    def demos(self, spec: Demos) -> Path:
        out = self.root / "demos" / spec.name
        if not (out / "meta" / "info.json").exists():
            from lerobot_opfa.envs.demos import record_demos

            record_demos(
                spec.task, spec.hand, spec.episodes, out, ",".join(spec.regions), spec.seed,
                f"local/{spec.name}", self.scale.n_points, "geometry", overwrite=True, arm=spec.arm,
                fps=spec.fps,
            )  # fmt: skip
        return out

    def merged(self, specs: tuple[Demos, ...]) -> Path:
        """All the demos in one dataset with cached latents (used by both co-training conditions)."""
        out = self.root / "merged" / _short_hash([d.name for d in specs])
        if not (out / "meta" / "info.json").exists():
            from lerobot_opfa.datasets.merge import merge_datasets

            merge_datasets(
                [self.demos(d) for d in specs], out, self.galr, f"local/{out.name}", overwrite=True
            )
        return out

    def dataset(self, training: Training) -> Path:
        """What the policy trains on: its one embodiment's demos, or all of them merged."""
        if training.condition == "wo_cotrain":
            return self.demos(training.demos[0])
        return self.merged(training.demos)

    # --- training ---------------------------------------------------------------------------------
    def checkpoint(self, training: Training) -> Path:
        """The trained policy's `pretrained_model` folder (trains it first if needed)."""
        out = self.root / "train" / training.name
        model = out / "checkpoints" / "last" / "pretrained_model"
        if model.exists():
            return model
        dataset = self.dataset(training)
        with atomic_directory(out, overwrite=True) as partial:
            args = [
                "--policy.type=opfa",
                f"--policy.action_space={CONDITIONS[training.condition]}",
                "--policy.wrist_normalization=shared",
                f"--policy.galr_path={self.galr}",
                f"--dataset.repo_id=local/{dataset.name}",
                f"--dataset.root={dataset}",
                f"--output_dir={partial}",
                f"--seed={training.seed}",
                "--policy.push_to_hub=false",
                "--wandb.enable=false",
                *self.scale.train_args(_frames(dataset), untrained=training.condition in CONTROLS),
            ]
            log = self.root / "logs" / f"train-{training.name}.log"
            # Its own loader and thread settings: the fastest measured (benchmarks/bench_training.py).
            self._run("lerobot-opfa", ["train", *args], log)
            (partial / "opfa_training.json").write_text(
                json.dumps(
                    {"condition": training.condition, "demos": [d.name for d in training.demos],
                     "commit": source_commit()}
                )
            )  # fmt: skip
        return model

    # --- evaluation -------------------------------------------------------------------------------
    def evaluate(self, evaluation: Evaluation) -> dict:
        """Successes of `scale.eval_episodes` seeded episodes (trains the policy first if needed)."""
        out = self.root / "eval" / f"{evaluation.name}.json"
        if out.exists():
            return json.loads(out.read_text())
        model = self.checkpoint(evaluation.training)
        scratch = self.root / "eval" / f".{evaluation.name}"
        shutil.rmtree(scratch, ignore_errors=True)
        args = [
            f"--policy.path={model}",
            "--policy.device=cpu" if not _cuda() else "--policy.device=cuda",
            "--env.type=opfa",
            f"--env.task={evaluation.task}",
            f"--env.hand={evaluation.hand}",
            f"--env.regions={','.join(evaluation.regions)}",
            "--env.obs_type=pointcloud",
            "--env.pointcloud_source=geometry",
            f"--env.n_points={self.scale.n_points}",
            f"--env.fps={evaluation.fps}",
            *([f"--env.arm={evaluation.arm}"] if evaluation.arm else []),
            f"--eval.n_episodes={self.scale.eval_episodes}",
            f"--eval.batch_size={min(self.scale.eval_batch_size, self.scale.eval_episodes)}",
            "--eval.use_async_envs=false",
            f"--seed={EVAL_SEED}",
            f"--output_dir={scratch}",
        ]
        if self.scale.episode_length:
            args.append(f"--env.episode_length={self.scale.episode_length}")
        start = time.monotonic()
        self._run("lerobot-eval", args, self.root / "logs" / f"eval-{evaluation.name}.log")
        info = json.loads((scratch / "eval_info.json").read_text())
        successes = [bool(s) for task in info["per_task"] for s in task["metrics"]["successes"]]
        result = {
            "condition": evaluation.training.condition,
            "task": evaluation.task,
            "hand": evaluation.hand,
            "arm": evaluation.arm,
            "fps": evaluation.fps,
            "regions": list(evaluation.regions),
            "training": evaluation.training.name,
            "successes": successes,
            "success_rate": sum(successes) / len(successes),
            "eval_seconds": round(time.monotonic() - start, 1),
            "commit": source_commit(),
            "training_commit": json.loads((model.parents[2] / "opfa_training.json").read_text()).get(
                "commit"
            ),
        }
        videos = sorted((scratch / "videos").rglob("*.mp4"))
        if videos:
            video = self.root / "videos" / f"{evaluation.name}.mp4"
            video.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(videos[0], video)
            result["video"] = str(video.relative_to(self.root))
        write_json(out, result)
        shutil.rmtree(scratch, ignore_errors=True)
        return result

    def failure_modes(self, evaluation: Evaluation, episodes: int) -> dict[str, int]:
        """How `episodes` seeded episodes of the cell end (`failures.OUTCOMES`), counted."""
        from lerobot_opfa.experiments.failures import OUTCOMES, episode_outcomes

        out = self.root / "failures" / f"{evaluation.name}-{episodes}ep.json"
        if out.exists():
            return json.loads(out.read_text())
        outcomes = episode_outcomes(
            self.checkpoint(evaluation.training), evaluation.task, evaluation.hand, evaluation.regions,
            self.scale.n_points, episodes, EVAL_SEED, self.scale.episode_length, evaluation.arm,
            evaluation.fps,
        )  # fmt: skip
        counts = {outcome: outcomes.count(outcome) for outcome in OUTCOMES}
        write_json(out, counts)
        return counts

    def _run(self, exe: str, args: list[str], log: Path) -> None:
        log.parent.mkdir(parents=True, exist_ok=True)
        path = Path(sys.executable).parent / exe
        with open(log, "w") as f:
            code = subprocess.run(
                [str(path), *args], stdout=f, stderr=subprocess.STDOUT, env=self.env
            ).returncode
        if code != 0:
            tail = log.read_text()[-3000:]
            raise RuntimeError(f"{exe} failed (exit {code}); log {log}:\n{tail}")


def source_commit() -> str | None:
    """The git commit of the package's source, if it is a checkout, with `-dirty` for uncommitted changes
    outside `benchmarks/results` (what a benchmark run writes there does not change the code it ran)."""
    package = Path(__file__).parent
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=package, capture_output=True, text=True)
    if head.returncode != 0 or not head.stdout.strip():
        return None
    paths = [":(top)", ":(top,exclude)benchmarks/results"]
    changes = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no", "--", *paths],
        cwd=package,
        capture_output=True,
        text=True,
    )
    return head.stdout.strip() + ("-dirty" if changes.stdout.strip() else "")


def write_json(path: Path, content) -> None:
    """Writes `path` whole or not at all: resuming reads every result file found, so none may be cut short."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")
    partial.write_text(json.dumps(content, indent=2))
    partial.replace(path)


def galr_identity(galr: str) -> str:
    """A local checkpoint by its weights' content (a regenerated one is another checkpoint), a Hub repo
    id by name."""
    weights = Path(checkpoints.resolve(galr)) / "model.safetensors"
    if weights.is_file():
        return "sha256:" + hashlib.sha256(weights.read_bytes()).hexdigest()
    return galr


def _frames(dataset: Path) -> int:
    return json.loads((dataset / "meta" / "info.json").read_text())["total_frames"]


def _cuda() -> bool:
    import torch

    return torch.cuda.is_available()
