"""This package's refusals in LeRobot's own command lines are one line (`command_errors`); the rest keeps
its traceback. The real command: test_rig's rollout of a checkpoint on a robot of another hand."""

from __future__ import annotations

import sys

import pytest

from lerobot_opfa import command_errors
from lerobot_opfa.datasets.joint_map import JointMap


def _raised(call):
    try:
        call()
    except BaseException:  # noqa: BLE001  (the test hands whatever was raised to the hook)
        return sys.exc_info()
    raise AssertionError("nothing raised")


def test_a_refusal_of_this_package_is_one_line_and_anything_else_goes_to_the_previous_hook(capsys):
    seen = []
    hook = command_errors.one_line_refusals(lambda *info: seen.append(info[0]))
    hook(*_raised(lambda: JointMap.from_dict({"hand": "umi"}, "a map")))  # this package's check
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "a map" in err and not seen
    hook(*_raised(lambda: int("x")))  # a ValueError, but not this package's
    hook(*_raised(lambda: command_errors.raised_by_this_package(42)))  # this package's, but a bug
    assert seen == [ValueError, AttributeError] and capsys.readouterr().err == ""


@pytest.mark.parametrize(
    ("value", "kept"), [("1", True), ("True", True), ("yes", True), ("0", False), ("no", False)]
)
def test_the_traceback_is_kept_on_request(capsys, monkeypatch, value, kept):
    monkeypatch.setenv(command_errors.SHOW_TRACEBACK, value)
    seen = []
    hook = command_errors.one_line_refusals(lambda *info: seen.append(info[0]))
    hook(*_raised(lambda: JointMap.from_dict({"hand": "umi"}, "a map")))
    assert bool(seen) is kept and capsys.readouterr().err.startswith("error: ") is not kept


@pytest.mark.parametrize(
    ("argv0", "expected"),
    [("/venv/bin/lerobot-eval", True), ("/venv/bin/lerobot-rollout", True), ("/venv/bin/lerobot-opfa", False),
     ("pytest", False)],
)  # fmt: skip
def test_only_lerobots_command_lines_get_the_hook(monkeypatch, argv0, expected):
    monkeypatch.setattr(sys, "argv", [argv0])
    assert command_errors.running_lerobot_command() is expected
    monkeypatch.setattr(sys, "excepthook", sys.__excepthook__)
    command_errors.shorten_refusals_in_lerobot_commands()
    assert (sys.excepthook is not sys.__excepthook__) is expected
