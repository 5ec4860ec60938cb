"""The README and docs/: every relative link resolves (the file, and the heading an anchor
names); the README stays a short page for users (at most 250 lines, naming no issue or commit)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(([^()\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def anchors(page: Path) -> set[str]:
    """GitHub's anchors for the headings of a Markdown page."""
    found: set[str] = set()
    for line in FENCE.sub("", page.read_text(encoding="utf-8")).splitlines():
        match = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if match:
            text = re.sub(r"[`*_]|\[([^\]]*)\]\([^)]*\)", r"\1", match.group(1))
            slug = re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")
            anchor, n = slug, 1
            while anchor in found:
                anchor, n = f"{slug}-{n}", n + 1
            found.add(anchor)
    return found


def links(page: Path) -> list[str]:
    return LINK.findall(FENCE.sub("", page.read_text(encoding="utf-8")))


def broken(page: Path) -> list[str]:
    bad = []
    for target in links(page):
        if re.match(r"^[a-z]+:", target):  # http:, https:, mailto: (not checked offline)
            continue
        path, _, anchor = target.partition("#")
        resolved = (page.parent / path).resolve() if path else page
        if not resolved.exists():
            bad.append(f"{target} (no such file)")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
            bad.append(f"{target} (no such heading)")
    return bad


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_links_resolve(page: Path):
    assert broken(page) == []


def test_the_checker_finds_broken_links(tmp_path: Path):
    """A missing file and a missing heading are both found (the check above can fail)."""
    (tmp_path / "b.md").write_text("# Title\n\n## A section\n")
    page = tmp_path / "a.md"
    page.write_text("[ok](b.md#a-section) [gone](c.md) [nohead](b.md#other) ![img](b.md)\n"
                    "```\n[in code](ignored.md)\n```\n")
    assert broken(page) == ["c.md (no such file)", "b.md#other (no such heading)"]


def test_readme_is_short_and_names_no_issue_or_commit():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250
    for number, line in enumerate(lines, 1):
        assert not re.search(r"\bissues?\s+#?\d+", line, re.I), f"README.md:{number} names an issue"
        for word in re.findall(r"\b[0-9a-f]{7,40}\b", line):
            assert not (re.search(r"\d", word) and re.search(r"[a-f]", word)), \
                f"README.md:{number} names a commit ({word})"


CODE_PATH = re.compile(r"`((?:addon|scripts|examples|tests|native)/[\w./*-]+)`")
USER_PAGES = [ROOT / "README.md", *sorted((ROOT / "docs" / "guide").glob("*.md"))]


def missing_code_paths(page: Path) -> list[str]:
    """Repository paths a page names in code spans (`addon/core/sh.py`, `native/src/*.c`) that do
    not exist: a file moved or renamed since the page was written."""
    text = page.read_text(encoding="utf-8")
    return [name for name in sorted(set(CODE_PATH.findall(text)))
            if not any(ROOT.glob(name.rstrip("/")))]


@pytest.mark.parametrize("page", USER_PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_code_paths_exist(page: Path):
    assert missing_code_paths(page) == []


def test_the_path_check_finds_moved_files(tmp_path: Path):
    page = tmp_path / "a.md"
    page.write_text("`addon/core/sh.py` `addon/core/no_such_module.py` `native/src/*.c`\n")
    assert missing_code_paths(page) == ["addon/core/no_such_module.py"]


DOTTED = re.compile(r"`(addon(?:\.\w+)+)")


def missing_dotted_names(page: Path) -> list[str]:
    """`addon.core.x.name` names a page gives that lead to no module (and, past the module, to no
    top-level name defined in it)."""
    missing = []
    for dotted in sorted(set(DOTTED.findall(page.read_text(encoding="utf-8")))):
        parts = dotted.split(".")
        for n in range(len(parts), 0, -1):
            base = ROOT.joinpath(*parts[:n])
            module = base.with_suffix(".py") if base.with_suffix(".py").exists() else \
                base / "__init__.py"
            if module.exists():
                break
        rest = parts[n:]
        defined = len(rest) == 1 and re.search(
            rf"^(?:def|class)\s+{rest[0]}\b|^{rest[0]}\s*[:=]", module.read_text(encoding="utf-8"),
            re.M)
        if rest and (len(rest) > 1 or not defined):
            missing.append(dotted)
    return missing


@pytest.mark.parametrize("page", USER_PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_dotted_names_exist(page: Path):
    assert missing_dotted_names(page) == []


def test_the_name_check_finds_moved_modules(tmp_path: Path):
    page = tmp_path / "a.md"
    page.write_text("`addon.core.render.composite.apply_shadow_catcher` `addon.core.sh` "
                    "`addon.core.composite.apply_shadow_catcher` `addon.core.sh.no_such_name`\n")
    assert missing_dotted_names(page) == ["addon.core.composite.apply_shadow_catcher",
                                          "addon.core.sh.no_such_name"]
