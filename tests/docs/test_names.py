"""What the docs (the README and all of docs/) and the code's comments and docstrings name of the
project lead somewhere: repository paths (`addon/core/sh.py`, `native/src/*.c`), dotted add-on
names (`addon.core.render.composite.compose`), a module's name with one of its names
(`splat_io.load`) and bare file names (`gather.py`); and the names of the flat modules that the
folders by stage replaced are gone, from the docs, the comments and the import aliases alike."""

from __future__ import annotations

import ast
import io
import re
import subprocess
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
SOURCES = sorted(p for folder in ("addon", "tests", "scripts", "benchmarks", "examples")
                 for p in (ROOT / folder).rglob("*.py"))
# The flat modules of before the folders by stage: their names, now gone, must not come back as
# a path, an alias or a name in prose.
RETIRED = ("bake_operator", "colmap_training", "image_io", "io_operators", "mesh_texture",
           "render_failures", "render_hooks", "render_layers", "render_panel", "render_state",
           "texture_bake", "train_config", "train_kernels", "train_operator", "training_panel")
# Roots that in the docs are Blender's data or operators, not the modules of the same name:
# `splat.crop` is the operator bpy.ops.splat.crop, `scene.render` a Scene's settings.
NOT_MODULES = {"splat", "scene"}
# Endings that make `name.ending` a file name rather than a module's name.
FILE_ENDINGS = {"blend", "c", "db", "dll", "exr", "glb", "h", "jpg", "json", "md", "npz", "ply",
                "png", "sh", "so", "splat", "spz", "sog", "toml", "txt", "webp", "zip", "abi3"}

TOP_FOLDERS = [ROOT / name for name in ("addon", "benchmarks", "docs", "examples", "native", "scripts",
                                        "tests")]
PATH = re.compile(r"(?<![\w/.-])((?:addon|benchmarks|examples|native|scripts|tests)/[\w./*-]*\w)")
DOTTED = re.compile(r"(?<![\w.])(addon(?:\.\w+)+)")
SPAN = re.compile(r"`([^`\n]+)`")
MODULE_NAME = re.compile(r"(?<![\w./-])([a-z_][a-z0-9_]*)\.([A-Za-z_]\w*)")
RETIRED_NAME = re.compile(r"\b(" + "|".join(RETIRED) + r")\b")


def module_of(parts: list[str]) -> tuple[Path, list[str]]:
    """The longest module `parts` name (a .py file or a package's __init__), and the rest."""
    for n in range(len(parts), 0, -1):
        base = ROOT.joinpath(*parts[:n])
        for module in (base.with_suffix(".py"), base / "__init__.py"):
            if module.is_file():
                return module, parts[n:]
    return ROOT / "addon" / "__init__.py", parts[1:]


def defines(module: Path, name: str) -> bool:
    """`module` defines `name` at its top level, or has a submodule of that name."""
    if module.name == "__init__.py" and module_of([*module.parent.relative_to(ROOT).parts, name])[1] == []:
        return True
    return bool(re.search(rf"^(?:def|class)\s+{name}\b|^{name}\s*[:=]",
                          module.read_text(encoding="utf-8"), re.M))


def missing_paths(text: str, page_folder: Path = ROOT) -> list[str]:
    """Repository paths that lead nowhere: from the root, from the page's folder (a link), or
    from a top-level folder (a tree's `tests/render_driver.c` under native/)."""
    return sorted({p for p in PATH.findall(text)
                   if not any(any(base.glob(p.rstrip("/")))
                              for base in (ROOT, page_folder, *TOP_FOLDERS))})


def missing_dotted_names(text: str) -> list[str]:
    missing = set()
    for dotted in DOTTED.findall(text):
        module, rest = module_of(dotted.split("."))
        if rest and (len(rest) > 1 or not defines(module, rest[0])):
            missing.add(dotted)
    return sorted(missing)


def add_on_modules() -> dict[str, list[Path]]:
    """Each add-on module's (and package's) name: the files it may be."""
    modules: dict[str, list[Path]] = {}
    for path in (ROOT / "addon").rglob("*.py"):
        modules.setdefault(path.parent.name if path.stem == "__init__" else path.stem, []).append(path)
    return modules


def tracked_file_names() -> set[str]:
    listed = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True).stdout
    return {Path(line).name for line in listed.splitlines()} | {p.name for p in SOURCES}


def missing_module_names(text: str, modules: dict[str, list[Path]], files: set[str]) -> list[str]:
    """Code spans naming `module.name` (a module of the add-on) whose module defines no such
    name, and spans that are a bare `name.py` no file of the repository has."""
    missing = set()
    for span in SPAN.findall(text):
        if re.fullmatch(r"[\w-]+\.py", span):
            if span not in files:
                missing.add(span)
            continue
        for module, name in MODULE_NAME.findall(span):
            if module in modules and module not in NOT_MODULES and name not in FILE_ENDINGS \
                    and name != "py" and not any(defines(p, name) for p in modules[module]):
                missing.add(f"{module}.{name}")
    return sorted(missing)


def commentary(path: Path) -> str:
    """A Python file's comments and docstrings (strings that stand as statements)."""
    source = path.read_text(encoding="utf-8")
    parts = [t.string for t in tokenize.generate_tokens(io.StringIO(source).readline)
             if t.type == tokenize.COMMENT]
    parts += [node.value.value for node in ast.walk(ast.parse(source))
              if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
              and isinstance(node.value.value, str)]
    return "\n".join(parts)


def import_aliases(path: Path) -> list[str]:
    return [alias.asname for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
            if isinstance(node, (ast.Import, ast.ImportFrom)) for alias in node.names
            if alias.asname]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_pages_name_what_exists(page: Path):
    text = page.read_text(encoding="utf-8")
    assert missing_paths(text, page.parent) == []
    assert missing_dotted_names(text) == []
    assert missing_module_names(text, add_on_modules(), tracked_file_names()) == []
    assert RETIRED_NAME.findall(text) == []


def test_comments_name_what_exists():
    found = []
    for path in SOURCES:
        text, where = commentary(path), path.relative_to(ROOT)
        found += [f"{where}: {name}" for name in missing_paths(text) + missing_dotted_names(text)
                  + RETIRED_NAME.findall(text)]
        found += [f"{where}: import ... as {a}" for a in import_aliases(path) if a in RETIRED]
    assert found == []


def test_the_checks_find_old_and_moved_names():
    """Each check can fail: a moved file, a moved module, a name a module lacks, a bare file
    name that no file has, an old flat module's name."""
    text = ("`addon/core/sh.py` `addon/core/no_such_module.py` `native/src/*.c` "
            "`addon.core.render.composite.compose` `addon.core.composite.compose` "
            "`addon.core.sh.no_such_name` `splat_io.load` `splat_io.no_such` `splat.crop` "
            "`gather.py` `nowhere.py` `scene.blend` (render_hooks)")
    assert missing_paths(text) == ["addon/core/no_such_module.py"]
    assert missing_dotted_names(text) == ["addon.core.composite.compose",
                                          "addon.core.sh.no_such_name"]
    assert missing_module_names(text, add_on_modules(), tracked_file_names()) == \
        ["nowhere.py", "splat_io.no_such"]
    assert RETIRED_NAME.findall(text) == ["render_hooks"]
    assert "The flat modules" in commentary(Path(__file__))
