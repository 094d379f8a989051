"""The paper's three experiment protocols as lists of evaluation cells (what to train on which demos, and
which embodiment to test where); `jobs.Workspace` runs the cells, `report` tabulates and plots them.

- spatial: each embodiment's demos come from its own regions of the table; every embodiment is tested in
  the regions that only the others' demos cover (the paper's zero-shot table, spatial columns).
- fewshot: k demos of a new embodiment, co-trained with a full set of another's (the few-shot figure).
- nine: nine embodiments, one region and eight demos each, tested on the whole table (the nine-embodiment
  figure).
"""

from __future__ import annotations

from dataclasses import dataclass

from lerobot_opfa.envs.regions import REGIONS
from lerobot_opfa.experiments.jobs import CONDITIONS, Demos, Evaluation, Training
from lerobot_opfa.experiments.scales import Scale

RING = (
    "near_right",
    "mid_right",
    "far_right",
    "far_center",
    "far_left",
    "mid_left",
    "near_left",
    "near_center",
)
"""The outer regions in order around the table; the centre region comes last."""
NINE_HANDS = (
    "umi",
    "robotiq_2f85",
    "robotiq_3f",
    "inspire",
    "inspire_tactile",
    "xhand",
    "leap",
    "svh",
    "shadow",
)


@dataclass(frozen=True)
class Cell:
    group: str
    """Column of the report (a task, a demo count, ...)."""
    evaluation: Evaluation

    @property
    def condition(self) -> str:
        return self.evaluation.training.condition


def split_regions(n: int) -> list[tuple[str, ...]]:
    """`n` disjoint, contiguous sets of regions, one per embodiment (the centre is used only for n = 9)."""
    if n == len(REGIONS):
        return [(r,) for r in (*RING, "mid_center")]
    if not 1 <= n <= len(RING):
        raise ValueError(f"cannot split the table's regions between {n} embodiments (1 to 8, or 9)")
    k = len(RING) // n
    return [RING[i * k : (i + 1) * k] for i in range(n)]


def _check_conditions(conditions: tuple[str, ...]) -> tuple[str, ...]:
    unknown = [c for c in conditions if c not in CONDITIONS]
    if unknown:
        raise ValueError(f"unknown condition(s) {unknown}; valid: {', '.join(CONDITIONS)}")
    return conditions


def co_training(
    group: str, task: str, demos: list[Demos], test_regions: list[tuple[str, ...]], conditions, seed: int
) -> list[Cell]:
    """Every condition for one set of per-embodiment demos; embodiment i is tested in test_regions[i]."""
    cells = []
    for condition in conditions:
        for i, d in enumerate(demos):
            training = Training(condition, (d,) if condition == "wo_cotrain" else tuple(demos), seed)
            cells.append(Cell(group, Evaluation(training, task, d.hand, test_regions[i])))
    return cells


def spatial(
    scale: Scale,
    tasks: tuple[str, ...],
    hands: tuple[str, ...],
    more_hands: tuple[str, ...] = (),
    conditions: tuple[str, ...] = tuple(CONDITIONS),
    seed: int = 0,
) -> list[Cell]:
    """`hands` on every task; `more_hands` (if given) on the first task as a larger co-training run."""
    cells = []
    runs = [(task, hands) for task in tasks] + ([(tasks[0], more_hands)] if more_hands else [])
    for task, run_hands in runs:
        regions = split_regions(len(run_hands))
        demos = [Demos(task, h, r, scale.demos, seed) for h, r in zip(run_hands, regions, strict=True)]
        unseen = [tuple(x for j, r in enumerate(regions) if j != i for x in r) for i in range(len(regions))]
        group = task if run_hands == hands else f"{task}, {len(run_hands)} embodiments"
        cells += co_training(group, task, demos, unseen, _check_conditions(conditions), seed)
    return cells


def fewshot(
    scale: Scale,
    task: str,
    new_hand: str,
    other_hand: str,
    conditions: tuple[str, ...] = tuple(CONDITIONS),
    seed: int = 0,
) -> list[Cell]:
    """For each k in `scale.fewshot_counts`: k demos of `new_hand` (+ `scale.demos` of `other_hand`)."""
    everywhere = tuple(REGIONS)
    other = Demos(task, other_hand, everywhere, scale.demos, seed)
    cells = []
    for k in scale.fewshot_counts:
        new = Demos(task, new_hand, everywhere, k, seed)
        for condition in _check_conditions(conditions):
            training = Training(condition, (new,) if condition == "wo_cotrain" else (new, other), seed)
            cells.append(Cell(str(k), Evaluation(training, task, new_hand, everywhere)))
    return cells


def nine(
    task: str,
    hands: tuple[str, ...] = NINE_HANDS,
    demos_per_hand: int = 8,
    conditions: tuple[str, ...] = tuple(CONDITIONS),
    seed: int = 0,
) -> list[Cell]:
    """Each hand gets one region and `demos_per_hand` demos; all are tested on the whole table."""
    regions = split_regions(len(hands))
    demos = [Demos(task, h, r, demos_per_hand, seed) for h, r in zip(hands, regions, strict=True)]
    everywhere = [tuple(REGIONS)] * len(hands)
    return co_training(task, task, demos, everywhere, _check_conditions(conditions), seed)
