"""The experiment runner at toy scale, end to end as a user runs it (scripted demos, merge, real
`lerobot-train` and `lerobot-eval` subprocesses), resume included; and the protocols' bookkeeping."""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import pytest
import torch

from lerobot_opfa.cli import main
from lerobot_opfa.envs.regions import REGIONS
from lerobot_opfa.experiments import protocols
from lerobot_opfa.experiments.failures import OUTCOMES
from lerobot_opfa.experiments.report import markdown_table, summarize, tables, wilson_interval, write_report
from lerobot_opfa.experiments.scales import get_scale


@pytest.mark.parametrize("n", [2, 3, 4, 8, 9])
def test_regions_split_is_disjoint(n):
    parts = protocols.split_regions(n)
    flat = [r for part in parts for r in part]
    assert len(parts) == n and len(flat) == len(set(flat)) and set(flat) <= set(REGIONS)
    assert len({len(p) for p in parts}) == 1


def test_wilson_interval():
    assert wilson_interval(0, 50) == pytest.approx((0.0, 0.0713), abs=1e-4)
    assert wilson_interval(25, 50) == pytest.approx((0.3664, 0.6336), abs=1e-4)
    assert wilson_interval(50, 50) == pytest.approx((0.9287, 1.0), abs=1e-4)


def test_table_pools_the_episodes_of_all_embodiments():
    def cell(hand, condition, wins):
        return {"group": "press_button", "hand": hand, "condition": condition,
                "successes": [True] * wins + [False] * (50 - wins)}  # fmt: skip

    rows = summarize([cell("umi", "wo_cotrain", 2), cell("leap", "wo_cotrain", 10), cell("umi", "opfa", 7)])
    lines = markdown_table(rows).splitlines()
    pooled = lines[lines.index("| **all embodiments**, episodes pooled (%) | |") + 1 :]
    assert pooled == ["| w/o co-training | 12 [7, 20] |", "| OPFA | 14 [7, 26] |"]  # 12/100, 7/50


def _transfer(cells):
    return [c for c in cells if c.kind == protocols.TRANSFER]


def test_protocol_cells():
    small = get_scale("small")
    cells = protocols.spatial(
        small, ("lift", "press_button"), ("inspire", "xhand"), ("umi", "inspire", "leap")
    )
    assert len(_transfer(cells)) == 2 * 2 * 4 + 3 * 4  # three conditions and the control
    for cell in _transfer(cells):  # every embodiment is tested where only the others' demos are
        own = next(d for d in cell.evaluation.training.demos if d.hand == cell.evaluation.hand).regions
        assert not set(own) & set(cell.evaluation.regions)
    naive = [c for c in _transfer(cells) if c.condition == "naive_cotrain" and c.group == "lift"]
    assert {len(c.evaluation.training.demos) for c in naive} == {2}
    alone = [c.evaluation for c in _transfer(cells) if c.condition == "wo_cotrain"]
    assert alone and all([d.hand for d in e.training.demos] == [e.hand] for e in alone)  # its own policy
    few = protocols.fewshot(small, "lift", "inspire", "xhand")
    assert [c.group for c in _transfer(few) if c.condition == "opfa"] == [
        "1",
        "2",
        "4",
        "8",
        "12",
        "18",
        "36",
    ]
    assert all(
        d.episodes == small.demos
        for c in few
        if c.condition == "opfa"
        for d in c.evaluation.training.demos[1:]
    )
    assert len(_transfer(protocols.nine("lift"))) == 9 * 4
    with pytest.raises(ValueError, match="unknown condition"):
        protocols.nine("lift", conditions=("oracle",))


@pytest.mark.parametrize(
    "cells",
    [
        protocols.spatial(get_scale("small"), ("press_button",), ("umi", "inspire", "leap")),
        protocols.objects(get_scale("small"), ("lift", "lift_box"), ("inspire", "xhand")),
        protocols.fewshot(get_scale("small"), "lift", "inspire", "xhand"),
        protocols.nine("press_button"),
    ],
    ids=["spatial", "object", "fewshot", "nine"],
)
def test_every_policy_is_tested_on_each_of_its_hands_own_demos(cells):
    inside = {
        (c.evaluation.training, c.evaluation.hand, c.evaluation.task, c.evaluation.regions)
        for c in cells
        if c.kind == protocols.IN_DISTRIBUTION
    }
    trainings = {c.evaluation.training for c in cells}
    assert inside == {(t, d.hand, d.task, d.covered) for t in trainings for d in t.demos}
    first = {}  # a policy's ceiling comes before its transfer cells
    for i, c in enumerate(cells):
        first.setdefault((c.evaluation.training, c.kind), i)
    assert all(first[(t, protocols.IN_DISTRIBUTION)] < first[(t, protocols.TRANSFER)] for t in trainings)


def test_in_distribution_is_where_the_demos_are():
    """k demos take the regions in turn: with fewer demos than regions, the others have none."""
    cells = protocols.fewshot(get_scale("small"), "press_button", "inspire", "xhand")
    inside = {
        (c.group, c.evaluation.hand): c.evaluation.regions
        for c in cells
        if c.kind == protocols.IN_DISTRIBUTION
    }
    assert inside[("1", "inspire")] == tuple(REGIONS)[:1]
    assert inside[("4", "inspire")] == tuple(REGIONS)[:4]
    assert inside[("12", "inspire")] == inside[("1", "xhand")] == tuple(REGIONS)


def test_the_control_is_opfas_policy_as_initialised_on_the_same_demos_and_is_never_flagged():
    """`untrained`: OPFA's training on the same demos, one step at learning rate 0 (weights as initialised,
    normalisation the dataset's); its low rate where its demos are is what a control shows, not a flag."""
    small = get_scale("small")
    control = small.train_args(5000, untrained=True)
    assert "--steps=1" in control and "--policy.optimizer_lr=0" in control
    assert "--policy.optimizer_lr=0" not in small.train_args(5000)
    cells = protocols.spatial(small, ("lift",), ("inspire", "xhand"), conditions=("opfa", "untrained"))
    trainings = {c.condition: c.evaluation.training for c in cells}
    assert trainings["untrained"].demos == trainings["opfa"].demos

    def row(condition, kind, wins):
        return {"group": "lift", "hand": "inspire", "condition": condition, "training": condition,
                "kind": kind, "successes": [True] * wins + [False] * (10 - wins)}  # fmt: skip

    rows = summarize([row(c, k, 1) for c in ("opfa", "untrained") for k in ("in_distribution", "transfer")])
    table = markdown_table([r for r in rows if r["kind"] == "transfer"])
    assert "| control: OPFA untrained | 10 [2, 40] |" in table and "| OPFA | 10 [2, 40] †" in table


def test_object_protocol_tests_each_hand_on_the_other_object():
    cells = _transfer(protocols.objects(get_scale("small"), ("lift", "lift_box"), ("inspire", "xhand")))
    for cell in cells:
        (own,) = [d for d in cell.evaluation.training.demos if d.hand == cell.evaluation.hand]
        assert cell.evaluation.task != own.task and cell.evaluation.regions == own.regions
    assert {c.condition for c in cells} == {"wo_cotrain", "naive_cotrain", "opfa", "untrained"}
    assert len(cells) == 8
    with pytest.raises(ValueError, match="one distinct task"):
        protocols.objects(get_scale("small"), ("lift", "lift"), ("inspire", "xhand"))


def test_transfer_cell_of_a_policy_failing_in_distribution_is_flagged():
    def cell(kind, wins, training="opfa-x"):
        return {"group": "lift", "hand": "inspire", "condition": "opfa", "kind": kind, "training": training,
                "successes": [True] * wins + [False] * (50 - wins)}  # fmt: skip

    rows = summarize([cell("in_distribution", 30), cell("transfer", 5)])
    transfer = next(r for r in rows if r["kind"] == "transfer")
    assert transfer["in_distribution_rate"] == 0.6 and transfer["ceiling_ok"] is False
    text = tables(rows)
    assert "| OPFA | 10 [4, 21] † |" in text and "| OPFA | 60 [46, 72] |" in text
    rows = summarize([cell("in_distribution", 45), cell("transfer", 5)])
    assert "†" not in tables(rows)


def test_report_of_perfect_cells(tmp_path):
    """50/50 cells: the interval holds the rate despite rounding, and the plot draws (error bars >= 0)."""
    for wins in range(51):
        low, high = wilson_interval(wins, 50)
        assert low <= wins / 50 <= high
    rows = summarize([
        {"group": "lift", "hand": h, "condition": c, "kind": k, "training": f"{c}-{h}", "task": "lift",
         "regions": ["mid_center"], "successes": [True] * 50}
        for h in ("inspire", "xhand") for c in ("wo_cotrain", "opfa") for k in ("transfer", "in_distribution")
    ])  # fmt: skip
    report = write_report(rows, tmp_path, "perfect", {"title": "t"})
    assert report["in_distribution_at_ceiling"] == {"threshold": 0.8, "entries": 4, "at_or_above": 4}
    assert (tmp_path / "perfect.png").read_bytes()[:4] == b"\x89PNG"


def test_spatial_experiment_toy_end_to_end_and_resume(tmp_path, capsys):
    """OPFA only: the w/o co-training policies are the same jobs on per-hand datasets (protocol_cells)."""
    work, report = tmp_path / "work", tmp_path / "report"
    argv = [
        "experiment", "spatial", "--scale", "toy", "--tasks", "press_button", "--hands", "umi,inspire",
        "--more-hands", "", "--conditions", "opfa", "--output-dir", str(work),
        "--report-dir", str(report), "--workers", "2", "--failure-episodes", "1",
    ]  # fmt: skip
    assert main(argv) == 0
    result = json.loads((report / "spatial_toy.json").read_text())
    rows = result["results"]
    assert {(r["hand"], r["condition"]) for r in rows} == {(h, "opfa") for h in ("umi", "inspire")}
    assert all(len(r["successes"]) == 2 and 0 <= r["ci95"][0] <= r["ci95"][1] <= 1 for r in rows)
    umi = next(r for r in rows if r["hand"] == "umi")
    assert set(umi["regions"]) == set(protocols.split_regions(2)[1])  # the other hand's regions
    inside = result["in_distribution"]  # one per trained policy and hand, where its demos are
    assert sorted(e["hand"] for e in inside) == ["inspire", "umi"]
    assert all(0 <= e["successes"] <= e["episodes"] == 2 for e in inside)
    covered = protocols.split_regions(2)[0][: get_scale("toy").demos]  # its 2 demos reach 2 of its regions
    assert next(e for e in inside if e["hand"] == "umi")["regions"] == list(covered)
    assert all("in_distribution_rate" in r and r["commit"] for r in rows)
    assert all(
        sorted(r["failure_modes"]) == sorted(OUTCOMES) and sum(r["failure_modes"].values()) == 1 for r in rows
    )
    assert "never touched the object (wrist)" in (report / "spatial_toy.md").read_text()
    assert (report / "spatial_toy.png").read_bytes()[:4] == b"\x89PNG"
    assert "| OPFA |" in (report / "spatial_toy.md").read_text()
    assert "OPFA" in capsys.readouterr().out

    # resume: a lost evaluation is redone, nothing else
    checkpoints = sorted((work / "train").glob("*/checkpoints/last/pretrained_model/model.safetensors"))
    assert len(checkpoints) == 1  # one OPFA policy of both hands
    stamps = [c.stat().st_mtime_ns for c in checkpoints]
    lost = sorted((work / "eval").glob("*.json"))[0]
    assert len(list((work / "eval").glob("*.json"))) == 4
    lost.unlink()
    assert main(argv) == 0
    assert lost.exists()
    assert [c.stat().st_mtime_ns for c in checkpoints] == stamps
    assert json.loads((report / "spatial_toy.json").read_text())["runs"] == 2

    # the env says its robot_type, so the policy refuses a hand it was not trained on
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_opfa.features import OBS_POINTCLOUD, ROBOT_TYPE
    from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

    opfa = checkpoints[0].parent
    policy = OpfaPolicy.from_pretrained(opfa)
    pre, _ = make_pre_post_processors(policy.config, pretrained_path=str(opfa))
    observation = {
        "observation.state": torch.zeros(1, 6 + 12),
        OBS_POINTCLOUD: torch.zeros(1, 3 * 64),
        ROBOT_TYPE: "xhand",
    }
    with pytest.raises(ValueError, match="robot_type 'xhand' names hand\\(s\\) xhand"):
        pre(observation)


def test_work_folder_refuses_to_resume_with_other_settings(tmp_path):
    from dataclasses import replace

    from lerobot_opfa.experiments.jobs import Workspace

    toy, galr = get_scale("toy"), tmp_path / "galr"
    galr.mkdir()
    (galr / "model.safetensors").write_bytes(b"weights")
    (galr / "config.json").write_text("{}")
    root = tmp_path / "work"
    Workspace(root, toy, str(galr))
    Workspace(root, toy, str(galr))  # same settings: resumes
    with pytest.raises(ValueError, match=r"other settings \(scale.epochs, scale.max_steps differ\)"):
        Workspace(root, replace(toy, epochs=2, max_steps=3), str(galr))
    (galr / "model.safetensors").write_bytes(b"regenerated weights")
    with pytest.raises(ValueError, match=r"other settings \(galr differ\)"):
        Workspace(root, toy, str(galr))
    (root / "settings.json").unlink()  # a folder from before settings were recorded ...
    (root / "train").mkdir()  # ... with results in it
    with pytest.raises(ValueError, match="no settings.json"):
        Workspace(root, toy, str(galr))


def test_training_length_is_counted_in_epochs_within_bounds():
    small = get_scale("small")
    assert small.steps(frames=small.batch_size * 100) == 100 * small.epochs
    assert small.steps(frames=1) == small.min_steps
    assert small.steps(frames=10**9) == small.max_steps
    assert get_scale("paper").steps(frames=128 * 1000) == 3000 * 1000


def test_run_log_counts_an_interrupted_run(tmp_path):
    """The wall-time log is rewritten after every cell, so a run that never finishes still counts."""
    from lerobot_opfa.experiments.commands import _durations

    (tmp_path / "runs.json").write_text("[100.0]")  # the older format: completed runs only
    start = time.monotonic() - 50
    first = _durations(tmp_path, start, "interrupted run")
    later = _durations(tmp_path, start, "interrupted run")  # a later cell replaces the run's entry
    assert first["runs"] == later["runs"] == 2
    assert 150 <= later["wall_seconds_all_runs"] < 160
    assert json.loads((tmp_path / "runs.json").read_text())["run 0"] == 100.0


def test_epochs_flag_names_the_report_and_lengthens_training(capsys):
    from lerobot_opfa.cli import build_parser
    from lerobot_opfa.experiments.commands import scale_of

    args = build_parser().parse_args(["experiment", "object", "--epochs", "100"])
    scale = scale_of(args)
    assert scale.name == "small_100ep" and scale.epochs == 100
    assert scale.steps(3200) == 2 * get_scale("small").steps(3200)
    assert main(["experiment", "object", "--epochs", "0"]) == 2
    assert "--epochs must be positive" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["spatial_small", "object_small_100ep", "fewshot_small", "nine_small"])
def test_committed_experiment_tables_regenerate_from_their_json(name):
    """Today's report code turns each committed experiment's cells into the tables committed with them (their
    rows; the prose between them has been reworded since some were written)."""
    report = json.loads((Path(__file__).parents[1] / "benchmarks" / "results" / f"{name}.json").read_text())
    transfer = report["results"]
    assert report["table_markdown"].startswith(markdown_table(transfer))
    inside = [
        {
            "kind": protocols.IN_DISTRIBUTION,
            **e,
            "successes": [True] * e["successes"] + [False] * (e["episodes"] - e["successes"]),
        }
        for e in report["in_distribution"]
    ]
    rows = summarize(
        [
            {k: v for k, v in r.items() if k not in ("episodes", "success_rate", "ci95")}
            for r in transfer + inside
        ]
    )

    def table_rows(text: str) -> list[str]:
        return [line for line in text.splitlines() if line.startswith("|")]

    assert table_rows(tables(rows)) == table_rows(report["table_markdown"])


def test_a_learnability_run_keeps_the_cells_another_run_recorded_meanwhile(tmp_path):
    """Two runs of the learnability benchmark from one clone share its JSON: each records its cell into the
    file as it is when the cell ends, so neither drops the other's (they used to, holding a stale copy)."""
    import importlib.util

    path = Path(__file__).parents[1] / "benchmarks" / "bench_learnability.py"
    spec = importlib.util.spec_from_file_location("bench_learnability", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    out = tmp_path / "learnability.json"
    cell = {"hand": "leap", "task": "lift", "action_space": "galr", "epochs": 50, "successes": 49}
    bench.record(out, cell)
    other = {**cell, "action_space": "raw", "successes": 50}
    out.write_text(json.dumps(json.loads(out.read_text()) + [other]))  # another process, meanwhile
    runs = bench.record(out, {**cell, "successes": 50})
    assert sorted((r["action_space"], r["successes"]) for r in runs) == [("galr", 50), ("raw", 50)]
    assert json.loads(out.read_text()) == runs


def test_the_stock_benchmark_resumes_past_finished_stages_and_keeps_the_other_rows_runs(tmp_path):
    """An interrupted bench_stock_policies run starts again at the stage it stopped in (a finished stage is
    not run again), and its results replace only the cells it ran."""
    import importlib.util

    benchmarks = Path(__file__).parents[1] / "benchmarks"
    sys.path.insert(0, str(benchmarks))
    try:
        spec = importlib.util.spec_from_file_location(
            "bench_stock_policies", benchmarks / "bench_stock_policies.py"
        )
        bench = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(bench)
    finally:
        sys.path.remove(str(benchmarks))
    out = tmp_path / "train_blind"
    bench.Stages(tmp_path / "work").run("train_blind", [out], [sys.executable, "-c", "print('trained')"])
    resumed = bench.Stages(tmp_path / "work")  # a new run in the same folder
    resumed.run("train_blind", [out], [sys.executable, "-c", "raise SystemExit(1)"])  # finished: not run
    assert list(resumed.done) == ["train_blind"] and resumed.done["train_blind"]["wall_s"] >= 0
    with pytest.raises(SystemExit, match="stage eval_blind_umi failed"):
        resumed.run("eval_blind_umi", [], [sys.executable, "-c", "raise SystemExit(1)"])
    cell = {"action_space": "galr", "hand": "umi", "control": "none", "successes": 43}
    kept = {"commit": "800a3e6", "runs": [cell, {**cell, "control": "untrained", "successes": 0}]}
    runs = bench.with_other_rows(kept, [{**cell, "control": "blind", "successes": 5, "commit": "abc"}])
    assert [(r["control"], r["successes"], r["commit"]) for r in runs] == [
        ("none", 43, "800a3e6"),
        ("untrained", 0, "800a3e6"),
        ("blind", 5, "abc"),
    ]
    redone = bench.with_other_rows(kept, [{**cell, "successes": 44, "commit": "abc"}])
    assert [(r["control"], r["successes"]) for r in redone] == [("untrained", 0), ("none", 44)]


def test_a_second_experiment_into_a_folder_in_use_is_refused_naming_the_run(tmp_path, capsys):
    from lerobot_opfa.output_folders import used_alone

    work = tmp_path / "work"
    with used_alone(work, "--output-dir"):  # the first run, in this process
        code = main(["experiment", "spatial", "--scale", "toy", "--output-dir", str(work)])
    error = capsys.readouterr().err
    assert code == 2 and f"--output-dir {work} is in use by another run (pid {os.getpid()})" in error, error
    assert not work.exists()  # the second run wrote nothing
