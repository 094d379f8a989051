"""Two hands per frame, measured on `lift_tray` (a hinged tray one hand cannot lift level) in `mid_center`.

- (a) Inspire on the left, XHand on the right, on the two-armed rig through LeRobot's tools: demos recorded
  with `lerobot-record`, one `galr` policy, deployed with `lerobot-rollout` beside `lerobot-eval`. That is
  `bench_rig.py --hands inspire+xhand --task lift_tray --record-s 10 --name rig_two_hands`; `--rig
  rig_two_hands` folds its results in here.
- (b) one policy co-trained on scripted demos of (Inspire, Inspire) and (XHand, XHand), evaluated with
  `lerobot-eval` on each pair it saw and on the mixed pair (Inspire, XHand) it never saw; `galr` (OPFA)
  beside `per_embodiment` (naive co-training), the same demos and protocol.

    MUJOCO_GL=egl .venv/bin/python benchmarks/bench_bimanual.py [--demos 20] [--epochs 30] [--episodes 50]
        [--work outputs/bimanual] [--rig rig_two_hands]
        [--conditions opfa,naive_cotrain] [--policy-arg=--policy.state_hand=false --name NAME]

Every step goes through the experiment runner (`lerobot-opfa train`, then `lerobot-eval`), whose steps are
idempotent: an interrupted benchmark resumes where it stopped. benchmarks/results/bimanual.json (a list
`runs`, each `{hands, task, action_space, trained_on, deploy, successes, episodes}`) and bimanual.png are
rewritten after every evaluation.
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from lerobot_opfa.envs.tasks import LiftTray  # noqa: E402
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
REGION = "mid_center"
TASK = LiftTray.name


def cells(demos: int, conditions: list[str]) -> list[tuple[Training, str]]:
    """(training, the pair it is evaluated on) of (b)."""
    pairs = tuple(Demos(TASK, hands, (REGION,), demos) for hands in ("inspire+inspire", "xhand+xhand"))
    return [
        (Training(condition, pairs), hands)
        for condition in conditions
        for hands in ("inspire+inspire", "xhand+xhand", "inspire+xhand")
    ]


def rig_rows(results: Path, name: str) -> list[dict]:
    """(a): the two-armed rig's results (`bench_rig.py --name NAME`), one row per deployment."""
    report = json.loads((results / f"{name}.json").read_text())
    rows = []
    for result in report["hands"]:
        hands = result["hand"].split("+")
        for deploy, key in (("lerobot-rollout", "rollout"), ("lerobot-eval", "eval")):
            rows.append({
                "hands": hands, "task": report["task"], "action_space": "galr", "trained_on": [hands],
                "deploy": deploy, "successes": result[f"{key}_successes"],
                "episodes": result[f"{key}_episodes"],
            })  # fmt: skip
    return rows


def record(out: Path, row: dict) -> list[dict]:
    """Every run in `out` with `row` in place of the same cell's (the file is read again just before)."""
    runs = json.loads(out.read_text())["runs"] if out.exists() else []
    key = ("hands", "action_space", "trained_on", "deploy")
    runs = [r for r in runs if any(r[k] != row[k] for k in key)] + [row]
    write_json(out, {"runs": runs})
    return runs


def plot(runs: list[dict], path: Path, trained_with: list[str] | tuple[str, ...] = ()) -> None:
    """One bar per run: its success on the pair it was evaluated on, grouped by what it trained on;
    `trained_with`: the extra training flags of (b), named in the title."""
    fig, ax = plt.subplots(figsize=(12, 5.4))
    labels = []
    for i, run in enumerate(runs):
        trained = "\n".join("+".join(p) for p in run["trained_on"])
        seen = run["hands"] in run["trained_on"]
        rate = 100 * run["successes"] / run["episodes"]
        ax.bar(i, rate, color="tab:blue" if run["action_space"] == "galr" else "tab:orange",
               hatch=None if seen else "//")  # fmt: skip
        ax.text(i, rate + 1, f"{run['successes']}/{run['episodes']}", ha="center", fontsize=8)
        labels.append(
            f"{'+'.join(run['hands'])}\n{run['action_space']}\n{run['deploy']}\ntrained on\n{trained}"
        )
    flags = f" (trained with {' '.join(trained_with)})" if trained_with else ""
    ax.set(xticks=range(len(runs)), ylabel="success (%)", ylim=(0, 110),
           title=f"{TASK}, {REGION}{flags}: hatched = a pair of hands the policy never saw")  # fmt: skip
    ax.set_xticklabels(labels, fontsize=7)
    ax.axhline(80, color="grey", lw=0.8, ls=":")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--demos", type=int, default=20)
    parser.add_argument("--epochs", type=int, default=30)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--work", type=Path, default=Path("outputs/bimanual"))
    parser.add_argument("--galr", default="default")
    parser.add_argument("--rig", help="fold in the two-armed rig's results, benchmarks/results/RIG.json")
    parser.add_argument("--results", type=Path, default=RESULTS)
    parser.add_argument("--name", default="bimanual", help="results as NAME.json and NAME.png")
    parser.add_argument("--conditions", default="opfa,naive_cotrain", help="(b)'s, comma-separated")
    parser.add_argument(
        "--policy-arg", action="append", default=[], help="a training flag more for (b), with its own --work"
    )
    args = parser.parse_args()
    scale = fixed_epochs(f"bimanual-{args.demos}x{args.epochs}", args.demos, args.epochs, args.episodes)
    scale = replace(scale, policy_args=(*scale.policy_args, *args.policy_arg))
    workspace = Workspace(args.work, scale, args.galr, threads=1)
    out, picture = args.results / f"{args.name}.json", args.results / f"{args.name}.png"
    for row in rig_rows(args.results, args.rig) if args.rig else []:
        plot(record(out, row), picture, args.policy_arg)
    for training, hands in cells(args.demos, args.conditions.split(",")):
        result = workspace.evaluate(Evaluation(training, TASK, hands, (REGION,)))
        row = {
            "hands": hands.split("+"),
            "task": TASK,
            "action_space": CONDITIONS[training.condition],
            "trained_on": [d.hand.split("+") for d in training.demos],
            "deploy": "lerobot-eval",
            "successes": sum(result["successes"]),
            "episodes": len(result["successes"]),
        }
        print(
            json.dumps(row), f"(commit {result['commit']}, training {result['training_commit']})", flush=True
        )
        plot(record(out, row), picture, args.policy_arg)


if __name__ == "__main__":
    main()
