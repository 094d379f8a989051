"""Argument types and the parser class of `lerobot-opfa`, and the error of a config flag in LeRobot's command
lines: a bad flag is one line, never a traceback."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from contextlib import contextmanager

from draccus.utils import DecodingError


class OneLineParser(argparse.ArgumentParser):
    """An argparse parser whose errors are one line (`prog: error: ...`), without the usage block."""

    def error(self, message: str):
        print(f"{self.prog}: error: {message} (see --help)", file=sys.stderr)
        sys.exit(2)


def positive_int(text: str) -> int:
    value = _number(text, int, "an integer")
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def non_negative_int(text: str) -> int:
    value = _number(text, int, "an integer")
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {text}")
    return value


def positive_float(text: str) -> float:
    value = _number(text, float, "a number")
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def non_negative_float(text: str) -> float:
    value = _number(text, float, "a number")
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def _number(text: str, kind: type, what: str):
    try:
        return kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None


class FlagError(DecodingError):
    """A refused `--env.*`, `--robot.*` or `--policy.*` value. LeRobot's command lines print a DecodingError
    with its message (`error: `env.hand`: ...`); a config's ValueError reaches the user only as draccus's
    "Couldn't instantiate class ..."."""


@contextmanager
def flag(name: str) -> Iterator[None]:
    """Raises the ValueErrors of the block as a `FlagError` of the flag `name` (e.g. `env.hand`)."""
    try:
        yield
    except ValueError as err:
        raise FlagError(tuple(name.split(".")), str(err)) from None
