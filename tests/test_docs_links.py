"""The README and docs/ pages link to each other by file and heading anchor; a moved or renamed
heading must fail here rather than leave a dead link for a reader."""
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _headings(text: str) -> list[str]:
    """Markdown headings outside fenced code blocks (a `# comment` in a bash block is not one)."""
    out, fence = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            fence = not fence
        elif not fence and re.match(r"#{1,6} ", line):
            out.append(line.lstrip("#").strip())
    return out


def anchors(text: str) -> set[str]:
    """GitHub's heading ids: lower case, punctuation other than - and _ dropped, spaces to -,
    repeats numbered -1, -2, ..."""
    seen: dict[str, int] = {}
    out = set()
    for h in _headings(text):
        slug = re.sub(r"[^\w\- ]", "", h.lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def test_anchor_rule_matches_github():
    text = "# A `b` c.d\n## x\n## x\n```\n# not a heading\n```\n## `hair-grid --head A ... -o G.png [o]`\n"
    assert anchors(text) == {"a-b-cd", "x", "x-1", "hair-grid---head-a---o-gpng-o"}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_local_links_resolve(page):
    text = page.read_text(encoding="utf-8")
    for target in LINK.findall(text):
        if re.match(r"[a-z]+:", target):  # http(s), mailto: not checked offline
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        assert dest.exists(), f"{page.name}: link to missing {target}"
        if anchor and dest.suffix == ".md":
            assert anchor in anchors(dest.read_text(encoding="utf-8")), \
                f"{page.name}: no heading #{anchor} in {dest.name}"


def test_readme_is_a_front_door():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "make demo" in text and "make test" in text
    assert len(text.splitlines()) <= 250
