"""The docs hold together: every citation of docs/physics.md names a section it has, every
relative link in the README and the docs pages points to a file that exists and, with an
anchor, to a heading that page has; the README stays a manual and every docs page opens with
what a user does."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PHYSICS = ROOT / "docs" / "physics.md"

# "docs/physics.md §5.1, §5.2" in code; "§2.5" in the bus configs, whose header names the page
SECTION = re.compile(r"§(\d+(?:\.\d+)?)")
CITATION = re.compile(r"docs/physics\.md((?:[ ,]*(?:and )?§\d+(?:\.\d+)?)+)")
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")
ANCHORED_LINK = re.compile(r"\]\(([^)#\s]*)#([^)\s]+)\)")

README_MAX_LINES = 300
# the first "## " heading of every docs page: what a user does (the command) and how to read
# its output, before any method or results
USER_SECTION = "## What you do"


def physics_sections() -> set[str]:
    """Numbers of the page's numbered headings: "## 5. Battery" -> "5", "### 5.2 ..." -> "5.2"."""
    heading = re.compile(r"^#{2,3} (\d+(?:\.\d+)?)\.? ", re.MULTILINE)
    return set(heading.findall(PHYSICS.read_text(encoding="utf-8")))


def cited_sections() -> dict[str, set[str]]:
    """Every section cited, with the files that cite it."""
    cited: dict[str, set[str]] = {}
    for path in sorted((ROOT / "ebus_env").rglob("*.py")):
        for match in CITATION.finditer(path.read_text(encoding="utf-8")):
            for number in SECTION.findall(match.group(1)):
                cited.setdefault(number, set()).add(str(path.relative_to(ROOT)))
    for path in sorted((ROOT / "configs").rglob("*.yaml")):
        for number in SECTION.findall(path.read_text(encoding="utf-8")):
            cited.setdefault(number, set()).add(str(path.relative_to(ROOT)))
    return cited


def test_the_physics_page_numbers_its_sections():
    sections = physics_sections()
    assert {"1", "1.2", "5.4", "9.4", "12"} <= sections
    # sections of a chapter are numbered from 1 without gaps
    for chapter in {s for s in sections if "." not in s}:
        subs = sorted(int(s.split(".")[1]) for s in sections if s.startswith(chapter + "."))
        assert subs == list(range(1, len(subs) + 1)), (chapter, subs)


def test_every_cited_section_exists():
    cited = cited_sections()
    assert len(cited) >= 10  # the effects, the configs and the calibrator cite the page
    missing = {number: sorted(files) for number, files in cited.items()
               if number not in physics_sections()}
    assert not missing, f"docs/physics.md has no section {missing}"


def test_no_citation_points_elsewhere():
    """A mention of physics.md is docs/physics.md: in code always with a section number; in a
    bus config the header may name the page, its comments then carry the numbers."""
    mention = re.compile(r"(?<![\w/])((?:[\w.-]+/)*)physics\.md")
    stray = []
    for path in sorted([*(ROOT / "ebus_env").rglob("*.py"), *(ROOT / "configs").rglob("*.yaml")]):
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for hit in mention.finditer(line):
                numbered = CITATION.match(line, hit.start())
                if hit.group(1) != "docs/" or (path.suffix == ".py" and not numbered):
                    stray.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not stray, "\n".join(stray)


def markdown_links() -> list[tuple[str, str]]:
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    links = set()
    for page in pages:
        for target in LINK.findall(page.read_text(encoding="utf-8")):
            if "://" not in target and not target.startswith("mailto:"):
                links.add((str(page.relative_to(ROOT)), target))
    return sorted(links)


@pytest.mark.parametrize(("page", "target"), markdown_links())
def test_relative_links_resolve(page, target):
    assert ((ROOT / page).parent / target).exists(), f"{page} links to {target}, which is missing"


def heading_anchors(page: Path) -> set[str]:
    """The anchors GitHub gives a page's headings: lower case, punctuation dropped, spaces to
    hyphens, "-1", "-2" on repeats; headings inside code blocks are not headings."""
    text = re.sub(r"^```.*?^```", "", page.read_text(encoding="utf-8"), flags=re.S | re.M)
    seen: dict[str, int] = {}
    anchors = set()
    for title in re.findall(r"^#{1,6} (.+?)\s*$", text, flags=re.M):
        slug = re.sub(r"[^\w\- ]", "", title.strip().lower()).replace(" ", "-")
        repeat = seen.get(slug, 0)
        seen[slug] = repeat + 1
        anchors.add(slug if repeat == 0 else f"{slug}-{repeat}")
    return anchors


def anchored_links() -> list[tuple[str, str, str]]:
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    links = set()
    for page in pages:
        for target, anchor in ANCHORED_LINK.findall(page.read_text(encoding="utf-8")):
            if "://" not in target and (not target or target.endswith(".md")):
                links.add((str(page.relative_to(ROOT)), target, anchor))
    return sorted(links)


def test_the_anchor_slugs_are_githubs():
    page = ROOT / "docs" / "physics.md"
    assert {"9-calibration", "52-internal-resistance"} <= heading_anchors(page)
    assert "installing-pytorch-cpu-for-the-rl-extra" in heading_anchors(ROOT / "docs" / "inputs.md")


def test_there_are_anchored_links():
    assert len(anchored_links()) >= 50


@pytest.mark.parametrize(("page", "target", "anchor"), anchored_links())
def test_anchors_resolve(page, target, anchor):
    path = (ROOT / page).parent / target if target else ROOT / page
    assert path.exists(), f"{page} links to {target}, which is missing"
    assert anchor in heading_anchors(path), f"{page} links to {target}#{anchor}: no such heading"


def test_the_readme_is_a_manual():
    """The README says what the tool does, how to install and use it, with the headline figures
    linked to the pages that hold them; results and method live in docs/."""
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, (
        f"README.md has {len(lines)} lines, at most {README_MAX_LINES}: move results and method "
        "to the docs page that regenerates them and link it")
    assert "## Headline figures" in lines


DOCS_PAGES = sorted((ROOT / "docs").glob("*.md"))


def test_there_are_docs_pages():
    assert len(DOCS_PAGES) >= 10


@pytest.mark.parametrize("page", DOCS_PAGES, ids=lambda p: p.name)
def test_each_docs_page_opens_with_what_a_user_does(page):
    lines = page.read_text(encoding="utf-8").splitlines()
    assert lines[0].startswith("# "), f"{page.name} opens with its title"
    first = next((line.rstrip() for line in lines if line.startswith("## ")), None)
    assert first == USER_SECTION, (
        f"{page.name}: its first section is {first!r}; open with {USER_SECTION!r}: the command "
        "a user runs and how to read its output")
    section = lines[lines.index(USER_SECTION) + 1:]
    section = section[:next((i for i, line in enumerate(section) if line.startswith("## ")),
                            len(section))]
    body = "\n".join(section)
    assert "```" in body or "`ebus " in body or "`python -m " in body, (
        f"{page.name}: the user section names no command")
