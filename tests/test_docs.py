"""The docs hold together: every relative link of the README, docs/ and experiments/ resolves to a file or
folder of the repository (and, with ``#anchor``, to a heading of that page), and every test a page names
(``tests/x/test_y.py::test_z``, ``test_y.py::test_z``, ``::test_z`` after one of them) exists."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md"), *(ROOT / "experiments").rglob("*.md")])
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
CODE = re.compile(r"```.*?```|`[^`\n]*`", re.S)


def _links(page: Path) -> list[str]:
    text = CODE.sub("", page.read_text())
    return [target for target in LINK.findall(text) if not re.match(r"[a-z][a-z0-9+.-]*:", target)]


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = CODE.sub("", page.read_text())
    return {_anchor(m) for m in re.findall(r"^#+ (.+)$", text, re.M)}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    broken = []
    for target in _links(page):
        path, _, anchor = target.partition("#")
        resolved = (page.parent / path).resolve() if path else page
        inside = resolved.exists() and ROOT in (resolved, *resolved.parents)
        if not inside or (anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved)):
            broken.append(target)
    assert not broken, f"{page.relative_to(ROOT)}: links to nothing: {broken}"


TESTS = ROOT / "tests"
TEST_REF = re.compile(r"(?<![\w/])((?:tests/[\w/]+/)?test_\w+\.py)((?:::\w+)?)|`::(test_\w+)`")


def _defines(files: list[Path], name: str) -> bool:
    return any(re.search(rf"^\s*(async )?def {name}\b", f.read_text(), re.M) for f in files)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_test_a_page_names_exists(page):
    missing, files = [], []
    for ref in TEST_REF.finditer(page.read_text()):
        path, name, alone = ref.groups()
        if alone:  # "::test_z" continues the file named before it on the page
            name, path = "::" + alone, None
        else:
            files = [ROOT / path] if path.startswith("tests/") else sorted(TESTS.rglob(path))
            files = [f for f in files if f.exists()]
            if not files:
                missing.append(ref.group(0))
                continue
        if name and not _defines(files, name[2:]):
            missing.append(ref.group(0))
    assert not missing, f"{page.relative_to(ROOT)} names tests that do not exist: {missing}"


DOCS_PAGE_BYTES = 20 * 1024  # a docs page is a reference a reader scans; a measurement's story goes to experiments/
README_BYTES = 15 * 1024


@pytest.mark.parametrize("page", sorted((ROOT / "docs").glob("*.md")), ids=lambda p: p.name)
def test_no_docs_page_is_over_20_kb(page):
    size = len(page.read_bytes())
    assert size <= DOCS_PAGE_BYTES, f"docs/{page.name} is {size} bytes (at most {DOCS_PAGE_BYTES}): split or condense it"


def test_the_readme_stays_under_15_kb():
    size = len((ROOT / "README.md").read_bytes())
    assert size <= README_BYTES, f"README.md is {size} bytes (at most {README_BYTES})"


# How a page was written is no part of what it says: work items and who ran what stay out of the docs.
WORK_HISTORY = re.compile(r"(?<!ManiSkill )\bissues? \d|\bthe issue's\b|\bthis\s+stop\b|\ble[n]t\b", re.I)


@pytest.mark.parametrize("page", [p for p in PAGES if p.parent.name == "docs" or p.name == "README.md"],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_pages_describe_the_software_not_their_history(page):
    found = [m.group(0) for m in WORK_HISTORY.finditer(page.read_text())]
    assert not found, f"{page.relative_to(ROOT)}: {found}"


OUTSIDE = re.compile(r"/work/|\.\./shared\b|devicekit")


def test_no_tracked_text_file_refers_to_files_outside_the_repository():
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, text=True)
    if listed.returncode != 0:
        pytest.skip("not a git checkout: the tracked files are unknown")
    found = []
    for name in filter(None, listed.stdout.split("\0")):
        path = ROOT / name
        if path == Path(__file__).resolve() or not path.is_file():
            continue
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue  # binary: a checkpoint records the paths of the machine that trained it
        found += [f"{name}:{text.count(chr(10), 0, m.start()) + 1}" for m in OUTSIDE.finditer(text)]
    assert not found, f"paths outside the repository: {found}"
