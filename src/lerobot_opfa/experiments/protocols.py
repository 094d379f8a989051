"""The paper's three experiment protocols as lists of evaluation cells (what to train on which demos, and
which embodiment to test where); `jobs.Workspace` runs the cells, `report` tabulates and plots them.

- spatial: each embodiment's demos come from its own regions of the table; every embodiment is tested in
  the regions that only the others' demos cover (the paper's zero-shot table, spatial columns).
- object: each embodiment's demos lift another object; every embodiment is tested on the others' objects
  (the paper's zero-shot table, object columns).
- fewshot: k demos of a new embodiment, co-trained with a full set of another's (the few-shot figure).
- nine: nine embodiments, one region and eight demos each, tested on the whole table (the nine-embodiment
  figure).

Every trained policy is also tested where it has data: each of its embodiments on its own demos' task, in
the regions its demos reach (`IN_DISTRIBUTION` cells). That ceiling tells a transfer failure from a policy
that fails at all.
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


TRANSFER, IN_DISTRIBUTION = "transfer", "in_distribution"
"""Cell kinds: the experiment's measurement, and the policy tested where its own demos are."""


@dataclass(frozen=True)
class Cell:
    group: str
    """Column of the report (a task, a demo count, ...)."""
    evaluation: Evaluation
    kind: str = TRANSFER

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


def in_distribution(group: str, training: Training) -> list[Cell]:
    """The policy tested with each of its embodiments where that embodiment's own demos are."""
    return [
        Cell(group, Evaluation(training, d.task, d.hand, d.covered), IN_DISTRIBUTION) for d in training.demos
    ]


def co_training(
    group: str, demos: list[Demos], tests: list[tuple[str, tuple[str, ...]]], conditions, seed: int
) -> list[Cell]:
    """Every condition for one set of per-embodiment demos; embodiment i is tested on tests[i], a (task,
    regions) pair. Each policy's in-distribution cells come before its transfer cells."""
    cells = []
    for condition in conditions:
        trainings = (
            [Training(condition, (d,), seed) for d in demos]
            if condition == "wo_cotrain"
            else [Training(condition, tuple(demos), seed)]
        )
        for training in trainings:
            cells += in_distribution(group, training)
        for i, d in enumerate(demos):
            training = trainings[i] if condition == "wo_cotrain" else trainings[0]
            task, regions = tests[i]
            cells.append(Cell(group, Evaluation(training, task, d.hand, regions)))
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
        unseen = [
            (task, tuple(x for j, r in enumerate(regions) if j != i for x in r)) for i in range(len(regions))
        ]
        group = task if run_hands == hands else f"{task}, {len(run_hands)} embodiments"
        cells += co_training(group, demos, unseen, _check_conditions(conditions), seed)
    return cells


OBJECT_REGIONS = ("mid_right", "mid_center", "mid_left")
"""Where the object experiment's demos and tests are: the table's middle row. Over the whole table, 24
demos left single-hand lift policies at 70-72 % where they had data (below the 80 % a ceiling needs)."""


def objects(
    scale: Scale,
    tasks: tuple[str, ...],
    hands: tuple[str, ...],
    regions: tuple[str, ...] = OBJECT_REGIONS,
    conditions: tuple[str, ...] = tuple(CONDITIONS),
    seed: int = 0,
) -> list[Cell]:
    """Hand i's demos do tasks[i] (one skill, another object each) in `regions`; every hand is tested there
    on the next hand's object."""
    if len(tasks) != len(hands) or len(set(tasks)) != len(tasks):
        raise ValueError(
            f"give one distinct task (object) per hand: {len(tasks)} tasks for {len(hands)} hands"
        )
    demos = [Demos(t, h, regions, scale.demos, seed) for t, h in zip(tasks, hands, strict=True)]
    others = [(tasks[(i + 1) % len(tasks)], regions) for i in range(len(tasks))]
    return co_training("/".join(tasks), demos, others, _check_conditions(conditions), seed)


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
            cells += in_distribution(str(k), training)  # the new hand's: where its k demos are
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
    everywhere = [(task, tuple(REGIONS))] * len(hands)
    return co_training(task, demos, everywhere, _check_conditions(conditions), seed)
