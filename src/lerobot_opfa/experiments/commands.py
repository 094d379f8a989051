"""`lerobot-opfa experiment spatial|object|fewshot|nine`: run one of the paper's protocols end to end
(demos -> merge -> `lerobot-opfa train` per condition -> `lerobot-eval` per cell) and write its table and
plot.

Re-running the same command resumes: finished demos, trainings and evaluations are found and skipped.
With `--workers N`, N policies train (and are evaluated) at once, each with its share of the CPU threads.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import replace
from datetime import datetime
from pathlib import Path

from tqdm import tqdm

from lerobot_opfa.envs.regions import parse_regions
from lerobot_opfa.experiments import protocols
from lerobot_opfa.experiments.jobs import CONDITIONS, Workspace, galr_identity, source_commit, write_json
from lerobot_opfa.experiments.report import summarize, write_report
from lerobot_opfa.experiments.scales import SCALES, Scale, get_scale
from lerobot_opfa.flags import non_negative_int, positive_int
from lerobot_opfa.output_folders import used_alone

TITLES = {
    "spatial": "Spatial generalisation: success in regions covered only by the other embodiments' demos",
    "object": "Object generalisation: success on the object only the other embodiment's demos handle",
    "fewshot": "Few-shot: success of a new embodiment against its number of demos",
    "nine": "Nine embodiments, one region and eight demos each: success on the whole table",
}


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    experiment = subparsers.add_parser("experiment", help="the paper's experiments").add_subparsers(
        dest="experiment", required=True
    )
    spatial = experiment.add_parser("spatial", help="w/o vs naive co-training vs OPFA, unseen regions")
    spatial.add_argument("--tasks", default="press_button,lift")
    spatial.add_argument("--hands", default="inspire,xhand")
    spatial.add_argument(
        "--more-hands", default="umi,inspire,xhand,leap", help="a larger run on the first task ('' skips)"
    )
    objects = experiment.add_parser("object", help="w/o vs naive co-training vs OPFA, the other's object")
    objects.add_argument("--tasks", default="lift,lift_box", help="one task (object) per hand")
    objects.add_argument("--hands", default="inspire,xhand")
    objects.add_argument(
        "--regions", default=",".join(protocols.OBJECT_REGIONS), help="where the demos and the tests are"
    )
    fewshot = experiment.add_parser("fewshot", help="success against the number of demos of a new hand")
    fewshot.add_argument("--task", default="press_button")
    fewshot.add_argument("--new-hand", default="inspire")
    fewshot.add_argument("--other-hand", default="xhand")
    nine = experiment.add_parser("nine", help="nine embodiments, one region and eight demos each")
    nine.add_argument("--task", default="press_button")
    nine.add_argument("--hands", default=",".join(protocols.NINE_HANDS))
    nine.add_argument("--demos-per-hand", type=positive_int, default=8)
    for parser in (spatial, objects, fewshot, nine):
        parser.add_argument("--scale", default="small", choices=list(SCALES))
        parser.add_argument(
            "--epochs", type=float, help="train this many epochs instead of the scale's (named in the report)"
        )
        parser.add_argument("--output-dir", type=Path, help="work folder (default outputs/experiments/NAME)")
        parser.add_argument("--report-dir", type=Path, help="where the JSON/MD/PNG go (default: output dir)")
        parser.add_argument(
            "--galr", default="long", help="GaLR checkpoint: packaged name (galr list), folder or Hub repo"
        )
        parser.add_argument("--conditions", default=",".join(CONDITIONS))
        parser.add_argument("--seed", type=int, default=0)
        parser.add_argument(
            "--workers",
            type=positive_int,
            default=1,
            help="policies trained at once (each gets CPUs / workers threads)",
        )
        parser.add_argument(
            "--failure-episodes", type=non_negative_int, default=20,
            help="episodes per transfer cell rolled out again to tell wrist from hand failures (0: none)",
        )  # fmt: skip
        parser.set_defaults(func=run)


def _names(text: str) -> tuple[str, ...]:
    return tuple(x.strip() for x in text.split(",") if x.strip())


def scale_of(args: argparse.Namespace) -> Scale:
    scale = get_scale(args.scale)
    if args.epochs is None:
        return scale
    if args.epochs <= 0:
        raise ValueError(f"--epochs must be positive, not {args.epochs}")
    return replace(scale, name=f"{scale.name}_{args.epochs:g}ep", epochs=args.epochs)


def cells_of(args: argparse.Namespace, scale: Scale) -> list[protocols.Cell]:
    conditions = _names(args.conditions)
    if args.experiment == "spatial":
        return protocols.spatial(
            scale, _names(args.tasks), _names(args.hands), _names(args.more_hands), conditions, args.seed
        )
    if args.experiment == "object":
        regions = tuple(parse_regions(args.regions))
        return protocols.objects(
            scale, _names(args.tasks), _names(args.hands), regions, conditions, args.seed
        )
    if args.experiment == "fewshot":
        return protocols.fewshot(scale, args.task, args.new_hand, args.other_hand, conditions, args.seed)
    return protocols.nine(args.task, _names(args.hands), args.demos_per_hand, conditions, args.seed)


def run(args: argparse.Namespace) -> int:
    if args.workers < 1:
        raise ValueError(f"--workers must be at least 1, not {args.workers}")
    start, run_id = time.monotonic(), datetime.now().isoformat()
    scale = scale_of(args)
    cells = cells_of(args, scale)
    name = f"{args.experiment}_{scale.name}"
    root = args.output_dir or Path("outputs/experiments") / name
    with used_alone(root, "--output-dir"):
        return _run(args, scale, cells, name, Path(root), start, run_id)


def _run(
    args: argparse.Namespace, scale: Scale, cells: list, name: str, root: Path, start: float, run_id: str
) -> int:
    """The experiment in the work folder `root`, which this process holds."""
    threads = max(1, (os.cpu_count() or 1) // args.workers) if args.workers > 1 else None
    workspace = Workspace(root, scale, args.galr, threads)
    meta = {
        "experiment": args.experiment,
        "title": TITLES[args.experiment],
        "scale": scale.name,
        "command": "lerobot-opfa " + shlex.join(sys.argv[1:] if sys.argv[0].endswith("lerobot-opfa") else []),
        "arguments": {k: str(v) for k, v in vars(args).items() if k != "func"},
        "galr_identity": galr_identity(args.galr),
        "commit": source_commit(),
        "machine": _machine(),
    }
    out_dir, curve = args.report_dir or root, args.experiment == "fewshot"
    trainings = list(dict.fromkeys(cell.evaluation.training for cell in cells))
    for training in tqdm(trainings, desc="demos and merged datasets", unit="policy"):
        workspace.dataset(training)  # in this process, one at a time, before the workers share them

    def evaluate_policy(training) -> dict[protocols.Cell, dict]:
        mine = [cell for cell in cells if cell.evaluation.training == training]
        results = {cell: workspace.evaluate(cell.evaluation) for cell in mine}
        for cell in mine:
            if cell.kind == protocols.TRANSFER and args.failure_episodes > 0:
                modes = workspace.failure_modes(cell.evaluation, args.failure_episodes)
                results[cell] = {**results[cell], "failure_modes": modes}
        return results

    results: dict[protocols.Cell, dict] = {}
    with (
        ThreadPoolExecutor(args.workers) as pool,
        tqdm(total=len(cells), desc=f"experiment {args.experiment}", unit="cell") as bar,
    ):
        for done in as_completed([pool.submit(evaluate_policy, t) for t in trainings]):
            results.update(done.result())
            bar.update(len(done.result()))
            rows = [
                {
                    "group": c.group,
                    "kind": c.kind,
                    **{k: v for k, v in results[c].items() if k != "success_rate"},
                }
                for c in cells
                if c in results
            ]
            report = write_report(
                summarize(rows), out_dir, name, {**meta, **_durations(root, start, run_id)}, curve
            )
    print(f"\n{TITLES[args.experiment]} ({scale.name} scale)\n")
    print(report["table_markdown"])
    print(f"report: {out_dir / name}.{{json,md,png}}")
    return 0


def _durations(root: Path, start: float, run_id: str) -> dict:
    """This invocation's wall time and the total over resumed runs. The log in the work folder is
    rewritten after every cell, so a run that is interrupted still counts up to its last finished cell."""
    log = root / "runs.json"
    runs = json.loads(log.read_text()) if log.exists() else {}
    if isinstance(runs, list):  # written before session 6: one entry per completed run
        runs = {f"run {i}": seconds for i, seconds in enumerate(runs)}
    runs[run_id] = round(time.monotonic() - start, 1)
    write_json(log, runs)
    return {
        "wall_seconds_this_run": runs[run_id],
        "wall_seconds_all_runs": round(sum(runs.values()), 1),
        "runs": len(runs),
    }


def _machine() -> dict:
    import torch

    return {
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
    }
