"""Every relative link of the README, docs/ and the research record lab/ points at a file that
exists and, where it names a section (`page.md#section`), at a heading of that page (GitHub's
anchor rule)."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [
    ROOT / "README.md",
    *sorted((ROOT / "docs").glob("*.md")),
    *sorted((ROOT / "lab").rglob("*.md")),
]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _strip_fences(text: str) -> str:
    """The text without fenced blocks (a '#' line there is not a heading)."""
    return re.sub(r"```.*?```", "", text, flags=re.S)


def _strip_code(text: str) -> str:
    """The text without fenced blocks and inline code spans (links there are not links)."""
    return re.sub(r"`[^`\n]*`", "", _strip_fences(text))


def anchors(page: Path) -> set:
    """GitHub's heading anchors of a markdown page: lower case, characters other than letters,
    digits, '-', '_' and spaces dropped, spaces to '-', a repeated anchor suffixed -1, -2, ..."""
    out, seen = set(), {}
    # a heading's inline code keeps its text in the anchor (only the backticks go)
    for line in _strip_fences(page.read_text(encoding="utf-8")).splitlines():
        m = re.match(r"^#{1,6} (.*)", line)
        if not m:
            continue
        slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
        if slug in seen:
            seen[slug] += 1
            slug = f"{slug}-{seen[slug]}"
        else:
            seen[slug] = 0
        out.add(slug)
    return out


def test_anchor_rule():
    page = ROOT / "lab" / "results-notes.md"
    got = anchors(page)
    assert "status" in got
    assert "how-to-record-a-disagreement" in got


def test_anchor_rule_on_a_made_page(tmp_path):
    p = tmp_path / "p.md"
    text = "# A (b), c: d.md\n## Same\n## Same\n```\n# not a heading\n```\n## Run `x-y` now\n"
    p.write_text(text, encoding="utf-8")
    assert anchors(p) == {"a-b-c-dmd", "same", "same-1", "run-x-y-now"}


def broken_links(page: Path) -> list:
    """The relative links of `page` whose file or heading does not exist, each with why."""
    bad = []
    for m in LINK.finditer(_strip_code(page.read_text(encoding="utf-8"))):
        target = m.group(1)
        if re.match(r"^[a-z]+:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path) if path else page
        if not dest.exists():
            bad.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            bad.append(f"{target}: no heading with that anchor in {dest.name}")
    return bad


def test_broken_links_are_found(tmp_path):
    (tmp_path / "other.md").write_text("# Here\n", encoding="utf-8")
    p = tmp_path / "p.md"
    links = "[a](other.md#here) [b](other.md#gone) [c](missing.md) [d](#top) [e](https://x.org/y)"
    p.write_text("# Top\n" + links + " `[f](inline.md)`\n", encoding="utf-8")
    assert broken_links(p) == [
        "other.md#gone: no heading with that anchor in other.md",
        "missing.md: no such file",
    ]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page):
    bad = broken_links(page)
    assert not bad, f"{page.relative_to(ROOT)}: " + "; ".join(bad)
