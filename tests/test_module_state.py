"""No module-level mutable state in `policy/`: what a pipeline or a policy knows lives in its own objects
(two pipelines in one process must not see each other), never in a module's dict, list, set or cache."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

POLICY = Path(__file__).parents[1] / "src" / "lerobot_opfa" / "policy"
MUTABLE_LITERALS = (ast.Dict, ast.List, ast.Set, ast.DictComp, ast.ListComp, ast.SetComp)
MUTABLE_CALLS = {"dict", "list", "set", "bytearray", "defaultdict", "OrderedDict", "Counter", "deque"}
CACHES = {"cache", "lru_cache", "cached"}


def _name(node: ast.AST) -> str:
    return node.attr if isinstance(node, ast.Attribute) else getattr(node, "id", "")


def module_state(source: str) -> list[str]:
    """The module-level mutable bindings, `global` statements and cached functions of `source`."""
    tree = ast.parse(source)
    found = []
    for node in tree.body:
        value = node.value if isinstance(node, (ast.Assign, ast.AnnAssign)) else None
        mutable_call = isinstance(value, ast.Call) and (
            _name(value.func) in MUTABLE_CALLS or _name(value.func).startswith("Weak")
        )
        if isinstance(value, MUTABLE_LITERALS) or mutable_call:
            found.append(f"line {node.lineno}: a mutable module-level value")
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            decorators = [_name(d.func if isinstance(d, ast.Call) else d) for d in node.decorator_list]
            found += [f"line {node.lineno}: @{d} on {node.name}" for d in decorators if d in CACHES]
    found += [
        f"line {n.lineno}: global {', '.join(n.names)}" for n in ast.walk(tree) if isinstance(n, ast.Global)
    ]
    return found


@pytest.mark.parametrize("path", sorted(POLICY.glob("*.py")), ids=lambda p: p.name)
def test_no_policy_module_keeps_state(path):
    assert module_state(path.read_text()) == []


def test_the_check_finds_each_kind_of_module_state():
    source = (
        "import functools, weakref\nA = {}\nB: list[int] = []\nC = weakref.WeakValueDictionary()\n"
        "@functools.cache\ndef f(): pass\ndef g():\n    global A\nD = (1, 2)\n"
    )
    assert [line.split(":")[0] for line in module_state(source)] == [
        "line 2", "line 3", "line 4", "line 6", "line 8",
    ]  # fmt: skip
