"""Success tables and plots of an experiment: rates with Wilson 95% intervals, Markdown tables in the
layout of the paper's (one block per embodiment, one row per condition, one column per group) for the
transfer cells and for the in-distribution ceiling beside them, and a PNG (bars with the ceiling marked,
or curves over the demo count for the few-shot experiment).

A transfer cell whose policy succeeds less than `CEILING` of the time on that embodiment's own demos
measures a policy that fails, not a transfer: it is flagged."""

from __future__ import annotations

import json
import math
from pathlib import Path

from lerobot_opfa.experiments.jobs import CONDITION_LABELS, CONTROLS
from lerobot_opfa.experiments.protocols import IN_DISTRIBUTION, TRANSFER

Z95 = 1.959964
CEILING = 0.8
FLAG = "†"


def wilson_interval(successes: int, n: int) -> tuple[float, float]:
    """95% Wilson score interval of a success rate (sane at 0 and n successes, unlike the normal one)."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    centre = (p + Z95**2 / (2 * n)) / (1 + Z95**2 / n)
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95**2 / (4 * n**2)) / (1 + Z95**2 / n)
    return max(0.0, min(p, centre - half)), min(1.0, max(p, centre + half))  # p inside despite rounding


def summarize(cells: list[dict]) -> list[dict]:
    """One row per evaluated cell with its rate and interval (cells carry group, condition, hand, the
    per-episode successes and, optionally, kind and training); a transfer row also gets its policy's
    in-distribution rate for that hand, when measured, and whether it reaches `CEILING`."""
    rows = []
    for cell in cells:
        wins, n = sum(cell["successes"]), len(cell["successes"])
        low, high = wilson_interval(wins, n)
        rows.append({"kind": TRANSFER, **cell, "episodes": n, "success_rate": wins / n, "ci95": [low, high]})
    ceiling = {(r["training"], r["hand"]): r["success_rate"] for r in rows if r["kind"] == IN_DISTRIBUTION}
    for row in rows:
        rate = ceiling.get((row.get("training"), row["hand"]))
        if row["kind"] == TRANSFER and rate is not None:
            row.update(in_distribution_rate=rate, ceiling_ok=rate >= CEILING)
    return rows


def markdown_table(rows: list[dict]) -> str:
    """One block per embodiment and, for several, a block pooling their episodes (the paper's averages)."""
    groups = list(dict.fromkeys(r["group"] for r in rows))
    hands = list(dict.fromkeys(r["hand"] for r in rows))
    conditions = [c for c in CONDITION_LABELS if any(r["condition"] == c for r in rows)]
    blocks = [(f"**{hand}** success rate (%)", [hand]) for hand in hands]
    if len(hands) > 1:
        blocks.append(("**all embodiments**, episodes pooled (%)", hands))
    lines = [f"| condition | {' | '.join(groups)} |", "|---|" + "---|" * len(groups)]
    for title, members in blocks:
        lines.append(f"| {title} |" + " |" * len(groups))
        for condition in conditions:
            cells = []
            for group in groups:
                mine = [
                    r
                    for r in rows
                    if (r["group"], r["condition"]) == (group, condition) and r["hand"] in members
                ]
                successes = [s for r in mine for s in r["successes"]]
                text = _rate_text(sum(successes), len(successes)) if successes else ""
                failing = condition not in CONTROLS and any(r.get("ceiling_ok") is False for r in mine)
                cells.append(f"{text} {FLAG}" if failing else text)
            lines.append(f"| {CONDITION_LABELS[condition]} | {' | '.join(cells)} |")
    return "\n".join(lines) + "\n"


def _rate_text(wins: int, n: int) -> str:
    low, high = wilson_interval(wins, n)
    return f"{100 * wins / n:.0f} [{100 * low:.0f}, {100 * high:.0f}]"


def plot(rows: list[dict], out: Path, title: str, curve: bool = False) -> Path:
    """Bars per (group, hand) and condition; with `curve`, success against the numeric group instead."""
    import numpy as np
    from matplotlib.figure import Figure

    inside = {(r["group"], r["hand"], r["condition"]): r for r in rows if r["kind"] == IN_DISTRIBUTION}
    rows = [r for r in rows if r["kind"] == TRANSFER]
    conditions = [c for c in CONDITION_LABELS if any(r["condition"] == c for r in rows)]
    fig = Figure(figsize=(max(6.0, 0.9 * len(rows) / max(1, len(conditions)) + 3), 4))
    ax = fig.subplots()
    if curve:
        for condition in conditions:
            mine = sorted((r for r in rows if r["condition"] == condition), key=lambda r: float(r["group"]))
            x = [float(r["group"]) for r in mine]
            y = [100 * r["success_rate"] for r in mine]
            ax.plot(x, y, marker="o", label=CONDITION_LABELS[condition])
            ax.fill_between(x, *[[100 * r["ci95"][i] for r in mine] for i in (0, 1)], alpha=0.15)
        ax.set_xscale("log", base=2)
        ax.set_xlabel("demonstrations of the new embodiment")
    else:
        keys = list(dict.fromkeys((r["group"], r["hand"]) for r in rows))
        index = {(r["group"], r["hand"], r["condition"]): r for r in rows}
        width = 0.8 / len(conditions)
        for j, condition in enumerate(conditions):
            found = [index.get((*k, condition)) for k in keys]
            x = np.arange(len(keys)) + (j - (len(conditions) - 1) / 2) * width
            y = np.array([100 * r["success_rate"] if r else np.nan for r in found])
            err = np.array([_error_bar(r) for r in found]).T
            ax.bar(x, y, width, yerr=err, capsize=2, label=CONDITION_LABELS[condition])
            ceiling = [inside.get((*k, condition)) for k in keys]
            y = np.array([100 * r["success_rate"] if r else np.nan for r in ceiling])
            label = "in distribution (own demos)" if j == 0 else None
            ax.scatter(x, y, marker="_", s=300 * width, color="k", zorder=3, label=label)
        multiple_groups = len({k[0] for k in keys}) > 1
        labels = ["\n".join([h, *g.split(", ")]) if multiple_groups else h for g, h in keys]
        ax.set_xticks(range(len(keys)), labels, fontsize=8)
    ax.set_ylabel("success rate (%), 95% Wilson interval")
    ax.set_ylim(0, 100)
    ax.set_title(title)
    ax.legend(fontsize=8)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return out


def _error_bar(row: dict | None) -> list[float]:
    if row is None:
        return [0.0, 0.0]
    rate, (low, high) = row["success_rate"], row["ci95"]
    return [100 * (rate - low), 100 * (high - rate)]


def in_distribution_entries(rows: list[dict]) -> list[dict]:
    """Each trained policy's success with each of its embodiments on its own demos."""
    return [
        {"group": r["group"], "condition": r["condition"], "hand": r["hand"], "task": r["task"],
         "regions": r["regions"], "training": r["training"], "successes": sum(r["successes"]),
         "episodes": r["episodes"], "success_rate": r["success_rate"], "ci95": r["ci95"]}
        for r in rows
        if r["kind"] == IN_DISTRIBUTION
    ]  # fmt: skip


def tables(rows: list[dict]) -> str:
    """The transfer table, then the in-distribution one (the ceiling), as Markdown."""
    transfer = [r for r in rows if r["kind"] == TRANSFER]
    inside = [r for r in rows if r["kind"] == IN_DISTRIBUTION]
    text = markdown_table(transfer)
    if any(r.get("ceiling_ok") is False for r in transfer):
        text += (
            f"\n{FLAG} the policy succeeds less than {100 * CEILING:.0f} % of the time on this embodiment's "
            "own demos (in distribution, below): a failing policy, not a transfer result.\n"
        )
    if inside:
        text += "\nIn distribution (each policy on its own demos' task, in the regions they reach):\n\n"
        text += markdown_table(inside)
    return text + failure_table(transfer)


def failure_table(rows: list[dict]) -> str:
    """How the transfer cells' episodes end, when measured (`failures`): the wrist never brought the hand
    to the object, or the hand touched it and still failed."""
    rows = [r for r in rows if "failure_modes" in r]
    if not rows:
        return ""
    episodes = sum(rows[0]["failure_modes"].values())
    lines = [
        f"\nHow transfer episodes end ({episodes} episodes per cell, rolled out again):\n",
        "| group | hand | condition | success | never touched the object (wrist) | touched, failed (hand) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        modes = r["failure_modes"]
        lines.append(
            f"| {r['group']} | {r['hand']} | {CONDITION_LABELS[r['condition']]} | {modes['success']} | "
            f"{modes['never_touched']} | {modes['touched_failed']} |"
        )
    return "\n".join(lines) + "\n"


def write_report(rows: list[dict], out_dir: Path, name: str, meta: dict, curve: bool = False) -> dict:
    """`<name>.json`, `<name>.md` and `<name>.png` in `out_dir`; returns the JSON's content."""
    out_dir.mkdir(parents=True, exist_ok=True)
    table = tables(rows)
    inside = in_distribution_entries(rows)
    at_ceiling = sum(e["success_rate"] >= CEILING for e in inside)
    report = {
        **meta,
        "results": [r for r in rows if r["kind"] == TRANSFER],
        "in_distribution": inside,
        "in_distribution_at_ceiling": {
            "threshold": CEILING,
            "entries": len(inside),
            "at_or_above": at_ceiling,
        },
        "table_markdown": table,
    }
    (out_dir / f"{name}.json").write_text(json.dumps(report, indent=2))
    header = f"# {meta.get('title', name)}\n\nCommand: `{meta.get('command', '')}`\n\n"
    (out_dir / f"{name}.md").write_text(header + table)
    plot(rows, out_dir / f"{name}.png", meta.get("title", name), curve)
    return report
