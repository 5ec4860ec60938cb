"""docs/architecture.md draws the house as it is: its table of imports between rooms is the
real import graph of addon/ (so a new arrow, or one that went away, shows here), no arrow points
up a layer, and its Layout names every folder and module of addon/."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ADDON = ROOT / "addon"
PAGE = ROOT / "docs" / "architecture.md"
# The layers, top first: a room's layer is the first whose prefix it starts with.
LAYERS = (("top", ""), ("blender", "blender/"), ("core", "core/"))


def room(module: Path) -> str:
    """A module's room: its folder under core/ or blender/ ("core/train/"), or the module itself
    when it sits directly in addon/, core/ or blender/ ("core/jobs.py", "cli.py")."""
    parts = module.relative_to(ADDON).parts
    if parts[0] in ("core", "blender") and len(parts) > 2:
        return f"{parts[0]}/{parts[1]}/"
    return "/".join(parts)


def module_path(dotted: list[str]) -> Path | None:
    base = ADDON.parent.joinpath(*dotted)
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def imported_modules(path: Path) -> set[Path]:
    """The add-on modules `path` imports (relative imports: the add-on imports itself so)."""
    package = list(path.relative_to(ADDON.parent).with_suffix("").parts)
    package = package[:-1]  # a module's package; a package's __init__ is in its own folder
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.ImportFrom) or not node.level:
            continue
        base = package[:len(package) - (node.level - 1)] + (node.module.split(".") if node.module else [])
        for alias in node.names:
            target = module_path(base + [alias.name]) or module_path(base)
            if target is not None:
                found.add(target)
    return found


def import_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for path in sorted(ADDON.rglob("*.py")):
        source = room(path)
        for target in imported_modules(path):
            if room(target) != source:
                graph.setdefault(source, set()).add(room(target))
    return graph


def drawn_graph(text: str) -> dict[str, set[str]]:
    """The page's table `| room | imports |` under "## Imports between rooms"."""
    section = text.split("## Imports between rooms", 1)[1].split("\n## ", 1)[0]
    graph = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 2 and cells[0].startswith("`"):
            graph[cells[0].strip("`")] = set(re.findall(r"`([^`]+)`", cells[1]))
    return graph


def layer(name: str) -> int:
    return max(i for i, (_, prefix) in enumerate(LAYERS) if name.startswith(prefix))


def test_the_drawn_arrows_are_the_real_ones():
    drawn, real = drawn_graph(PAGE.read_text(encoding="utf-8")), import_graph()
    assert {k: sorted(v) for k, v in drawn.items()} == {k: sorted(v) for k, v in real.items()}


def test_no_arrow_points_up_a_layer():
    upward = [f"{a} -> {b}" for a, targets in import_graph().items() for b in targets
              if layer(b) < layer(a)]
    assert upward == []


def test_the_graph_reads_relative_imports(tmp_path):
    """The graph finds `from ..core import native` and `from .state import x` (it can fail)."""
    graph = import_graph()
    assert "core/native.py" in graph["blender/sources/"]
    assert "blender/render/" not in graph.get("blender/render/", set())  # within a room: no arrow
    assert layer("core/train/") == 2 and layer("blender/io/") == 1 and layer("cli.py") == 0


def test_the_layout_names_every_module():
    layout = PAGE.read_text(encoding="utf-8").split("## Layout", 1)[1]
    words = set(re.findall(r"[\w.]+", layout))
    missing = sorted(str(p.relative_to(ADDON)) for p in ADDON.rglob("*.py")
                     if p.stem != "__init__" and p.stem not in words and p.name not in words
                     or p.stem == "__init__" and p.parent != ADDON and p.parent.name not in words)
    assert missing == []
