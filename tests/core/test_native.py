"""`addon/core/native.py` is the one door to `splatcore`: a typed function there for every
native entry point, and no other add-on module that imports or calls the extension. Each entry
point's arguments are declared once (native/src/bindings.h, read through `splatcore.signature`)
and the door passes them by name, so it holds no copy of their order."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import numpy as np
import pytest
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


# Entry points without a table of their own: no arguments, or one object (METH_O).
NO_TABLE = {"release_buffers", "cpu_count", "signature"}
ONE_OBJECT = {"checksum", "train_state_info"}


def _door_calls() -> list[ast.Call]:
    """The door's calls `splatcore().<entry>(...)`."""
    tree = ast.parse((ADDON / "core" / "native.py").read_text(encoding="utf-8"))
    return [node for node in ast.walk(tree) if isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute) and isinstance(node.func.value, ast.Call)
            and getattr(node.func.value.func, "id", None) == "splatcore"]


def test_every_entry_point_has_a_table():
    for name in dir(splatcore):
        if callable(getattr(splatcore, name)) and not name.startswith("_") and name not in NO_TABLE:
            table = splatcore.signature(name)
            assert table and all(len(row) == 3 for row in table), name
    with pytest.raises(ValueError, match="no entry point"):
        splatcore.signature("no_such_entry_point")


def test_the_door_passes_every_argument_by_name():
    """No positional argument (so no order to keep in step with module.c), and every name one
    the entry point's table has."""
    calls = _door_calls()
    assert {"render", "backward", "adam"} <= {c.func.attr for c in calls}  # the calls are found
    for call in calls:
        entry = call.func.attr
        if entry in NO_TABLE | ONE_OBJECT:
            continue
        assert call.args == [], f"native.py passes {entry} positional arguments"
        names = {row[0] for row in splatcore.signature(entry)}
        given = {k.arg for k in call.keywords if k.arg is not None}
        assert given <= names, f"{entry}: {sorted(given - names)} are not its arguments"


def test_arguments_by_name_in_any_order_and_missing_ones_named():
    """The native parser takes the table's names in any order, and says which one is missing
    or which name is not its own."""
    image = np.zeros((8, 8, 3), np.float32)
    by_name = dict(out_grad=None, threads=1, lambda_dssim=0.2, target=image, image=image)
    assert splatcore.l1_ssim(**by_name) == splatcore.l1_ssim(image, image, 0.2, 1, None)
    with pytest.raises(TypeError, match="missing required argument 'target'"):
        splatcore.l1_ssim(image=image, lambda_dssim=0.2, threads=1, out_grad=None)
    with pytest.raises(TypeError, match="unexpected keyword"):
        splatcore.l1_ssim(**by_name, lambda_ssim=0.2)
    with pytest.raises(TypeError, match="multiple values for argument 'image'"):
        splatcore.l1_ssim(image, **by_name)
