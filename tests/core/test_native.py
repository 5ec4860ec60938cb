"""`addon/core/native.py` is the one door to `splatcore`: a typed function there for every
native entry point, and no other add-on module that imports or calls the extension."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import splatcore

from addon.core import native

ADDON = Path(__file__).resolve().parents[2] / "addon"
# Entry points whose Python side has another name (`cpu_count` is Python's own count there).
RENAMED = {"cpu_count": "native_cpu_count"}


def test_a_function_for_every_entry_point():
    entry_points = sorted(name for name in dir(splatcore)
                          if not name.startswith("_") and callable(getattr(splatcore, name)))
    assert entry_points, "splatcore exports no functions"
    for name in entry_points:
        function = getattr(native, RENAMED.get(name, name), None)
        assert inspect.isfunction(function), f"addon/core/native.py has no function for {name}"
        assert function.__doc__, f"native.{function.__name__} has no docstring"
        hints = inspect.get_annotations(function)
        assert "return" in hints, f"native.{function.__name__} has no return type"


def _mentions_splatcore(tree: ast.AST) -> list[int]:
    """Lines that import `splatcore` or call `native.splatcore()`."""
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import) and any(a.name == "splatcore" for a in node.names):
            lines.append(node.lineno)
        elif isinstance(node, ast.ImportFrom) and node.module == "splatcore":
            lines.append(node.lineno)
        elif isinstance(node, ast.Attribute) and node.attr == "splatcore":
            lines.append(node.lineno)
    return lines


def test_no_other_module_calls_splatcore():
    offenders = []
    for path in sorted(ADDON.rglob("*.py")):
        if path == ADDON / "core" / "native.py":
            continue
        for line in _mentions_splatcore(ast.parse(path.read_text(encoding="utf-8"))):
            offenders.append(f"{path.relative_to(ADDON.parent)}:{line}")
    assert offenders == [], "only addon/core/native.py may call splatcore: " + ", ".join(offenders)


def test_the_door_detects_a_call():
    """The check above finds both ways in (so it cannot pass by finding nothing)."""
    assert _mentions_splatcore(ast.parse("import splatcore\n")) == [1]
    assert _mentions_splatcore(ast.parse("x = native.splatcore().render\n")) == [1]
    assert _mentions_splatcore(ast.parse("x = native.render\n")) == []
