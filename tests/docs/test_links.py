"""The README and docs/: every relative link resolves (the file, and the heading an anchor
names); the README stays a short page for users (at most 250 lines, naming no issue or commit).
What the pages name in code spans (paths, modules) is checked by test_names.py."""

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
