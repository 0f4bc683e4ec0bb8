"""The docs hold together: every relative link of the README, docs/ and experiments/ resolves to a file or
folder of the repository (and, with ``#anchor``, to a heading of that page), and every test a page names
(``tests/x/test_y.py::test_z``, ``test_y.py::test_z``, ``::test_z`` after one of them) exists."""

from __future__ import annotations

import re
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
