"""The docs hold together: every citation of docs/physics.md names a section it has, and every
relative link in the README and the docs pages points to a file that exists."""

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
