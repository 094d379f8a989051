"""How a mistake that this package's checks catch reaches a user of LeRobot's own command lines
(`lerobot-train`, `lerobot-eval`, `lerobot-rollout`, `lerobot-record`): as one line, as in `lerobot-opfa`.

LeRobot's entry points catch only draccus's parse errors; a check of this package that fails while they run
(a policy given an env whose observations it cannot read, a dataset without the clouds a policy reads)
would end a page of traceback. LeRobot offers no seam for it, Python does: `sys.excepthook`, which the plugin
sets when one of LeRobot's command lines loads it. Only this package's own refusals are shortened (a
`ValueError`, `FileNotFoundError` or `FileExistsError` raised by a function of the package); anything else,
and everything with LEROBOT_OPFA_TRACEBACK=1 (or true, yes), keeps Python's traceback."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path
from types import TracebackType

REFUSALS = (ValueError, FileNotFoundError, FileExistsError)
SHOW_TRACEBACK = "LEROBOT_OPFA_TRACEBACK"
"""Set to 1, true or yes (any case) to keep the traceback; any other value, 0 included, leaves it off."""
PACKAGES = ("lerobot_opfa", "lerobot_policy_opfa")

ExceptHook = Callable[[type[BaseException], BaseException, TracebackType | None], object]


def raised_by_this_package(traceback: TracebackType | None) -> bool:
    """Whether the innermost frame of `traceback` is a function of this package."""
    last = None
    while traceback is not None:
        last, traceback = traceback, traceback.tb_next
    module = "" if last is None else str(last.tb_frame.f_globals.get("__name__", ""))
    return module.split(".")[0] in PACKAGES


def traceback_requested() -> bool:
    return os.environ.get(SHOW_TRACEBACK, "").strip().lower() in ("1", "true", "yes")


def one_line_refusals(previous: ExceptHook) -> ExceptHook:
    """An excepthook printing this package's refusals as `error: ...`, and handing the rest to `previous`."""

    def hook(kind, error, traceback):
        refusal = issubclass(kind, REFUSALS) and raised_by_this_package(traceback)
        if refusal and not traceback_requested():
            print(f"error: {error}", file=sys.stderr)
        else:
            previous(kind, error, traceback)

    return hook


def running_lerobot_command() -> bool:
    """Whether this process is one of LeRobot's command lines (`lerobot-eval`, `python -m
    lerobot.scripts.lerobot_eval`, a rank of `torchrun lerobot-train`)."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    script = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ""
    return (spec is not None and spec.name.startswith("lerobot.scripts.")) or (
        script.startswith("lerobot-") and script != "lerobot-opfa"
    )


def shorten_refusals_in_lerobot_commands() -> None:
    """Sets the hook in LeRobot's command lines, where no one else has set one."""
    if running_lerobot_command() and sys.excepthook is sys.__excepthook__:
        sys.excepthook = one_line_refusals(sys.excepthook)
