"""The documentation holds together: every relative Markdown link in the README, STYLE.md,
web/README.md and docs/ points at a file that exists (and at a heading of it, where the link
names one), every page of docs/ is linked from the README, the README's "What it is" stays
short, and the style guide the lint configuration cites exists."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted(
    [
        ROOT / "README.md",
        ROOT / "STYLE.md",
        ROOT / "web" / "README.md",
        *(ROOT / "docs").glob("*.md"),
    ]
)

_FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.MULTILINE | re.DOTALL)
# [text](target) or [text](target "title"); the text may hold backticks and span lines.
_LINK = re.compile(r"\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_HEADING = re.compile(r"^(#{1,6})\s+(.+?)\s*#*\s*$", re.MULTILINE)


def _prose(text: str) -> str:
    """The page without its fenced code blocks (a ``# comment`` there is not a heading and
    ``[x](y)`` there is not a link)."""
    return _FENCE.sub("", text)


def links(text: str) -> list[str]:
    return _LINK.findall(_prose(text))


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped (``-`` and ``_``
    kept), spaces to hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link's text only
    text = text.lower().strip()
    text = "".join(c for c in text if c.isalnum() or c in " -_")
    return text.replace(" ", "-")


def anchors(text: str) -> set[str]:
    """Every heading's anchor, with GitHub's ``-1``, ``-2`` suffixes for repeats."""
    seen: dict[str, int] = {}
    out = set()
    for _, heading in _HEADING.findall(_prose(text)):
        base = slug(heading)
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def broken_links(page: Path, root: Path = ROOT) -> list[str]:
    """The relative links of ``page`` that do not resolve within ``root``, with the reason."""
    bad = []
    for target in links(page.read_text(encoding="utf-8")):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):
            continue  # http:, https:, mailto: ...: not ours to check offline
        path_part, _, anchor = target.partition("#")
        dest = (page.parent / path_part).resolve() if path_part else page
        if not dest.is_relative_to(root):
            bad.append(f"{target}: outside the repository")
        elif not dest.exists():
            bad.append(f"{target}: no such file {dest.relative_to(root)}")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest.read_text("utf-8")):
            bad.append(f"{target}: {dest.relative_to(root)} has no heading #{anchor}")
    return bad


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_relative_links_resolve(page: Path) -> None:
    assert page.exists(), page
    assert broken_links(page) == []


def test_link_checker_finds_broken_links(tmp_path: Path) -> None:
    """The checker itself: a missing file, a missing heading and a link in a code block."""
    tmp_path = tmp_path.resolve()
    (tmp_path / "other.md").write_text("# Other page\n\n## A section (`code`)\n")
    page = tmp_path / "page.md"
    page.write_text(
        "# Page\n\n[ok](other.md) [ok too](other.md#a-section-code) [self](#page)\n"
        "[gone](missing.md) [no heading](other.md#nowhere)\n"
        "[spans\nlines](other.md#other-page) [`code` text](https://example.org/x)\n\n"
        "```\n# not a heading\n[not a link](missing-too.md)\n```\n"
    )
    assert links(page.read_text()) == [
        "other.md",
        "other.md#a-section-code",
        "#page",
        "missing.md",
        "other.md#nowhere",
        "other.md#other-page",
        "https://example.org/x",
    ]
    assert broken_links(page, root=tmp_path) == [
        "missing.md: no such file missing.md",
        "other.md#nowhere: other.md has no heading #nowhere",
    ]


def test_every_docs_page_is_linked_from_the_readme() -> None:
    readme = ROOT / "README.md"
    linked = {(ROOT / t.partition("#")[0]).resolve() for t in links(readme.read_text("utf-8"))}
    pages = {p.resolve() for p in (ROOT / "docs").iterdir() if p.is_file()}
    assert sorted(str(p.relative_to(ROOT)) for p in pages - linked) == []
    assert (ROOT / "STYLE.md").resolve() in linked


def test_readme_says_what_it_is_in_at_most_25_lines_then_how_to_use_it() -> None:
    text = (ROOT / "README.md").read_text("utf-8")
    sections = [m.group(2) for m in _HEADING.finditer(_prose(text)) if m.group(1) == "##"]
    assert sections[:2] == ["What it is", "Using it"]
    body = text.split("\n## What it is\n", 1)[1].split("\n## ", 1)[0]
    assert len(body.strip("\n").splitlines()) <= 25


def test_the_cited_style_guide_exists() -> None:
    """pyproject.toml and tests/test_codebase.py cite the style guide by its path."""
    cited = set()
    for source in ("pyproject.toml", "tests/test_codebase.py"):
        cited |= set(re.findall(r"[\w/.-]*STYLE\.md", (ROOT / source).read_text("utf-8")))
    assert cited, "neither pyproject.toml nor tests/test_codebase.py cites a style guide"
    assert sorted(c for c in cited if not (ROOT / c).is_file()) == []
