"""The docs' cluster commands work as written (issue 40: the README's ``ray start --head`` ...
``evaluator.address=auto`` lacked ``export RAY_AUTH_MODE=token``, so the second node and the run were refused,
"the cluster refused this machine's connection"): every shell block of docs/ that starts or joins a Ray cluster
exports the token mode before its first such line."""

from __future__ import annotations

import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"
JOINS = re.compile(r"ray start|evaluator\.address=(auto|\d|[A-Z_]+:)")


def _bash_blocks(text: str) -> list[list[str]]:
    return [block.splitlines() for block in re.findall(r"```bash\n(.*?)```", text, re.S)]


def test_every_docs_block_that_joins_a_cluster_exports_the_token_mode_first():
    checked = 0
    for page in [*sorted(DOCS.glob("*.md")), DOCS.parent / "README.md"]:
        for lines in _bash_blocks(page.read_text()):
            first = next((i for i, line in enumerate(lines) if JOINS.search(line.split("#")[0])), None)
            if first is None:
                continue
            checked += 1
            assert any(line.startswith("export RAY_AUTH_MODE=token") for line in lines[:first]), \
                (page.name, lines)
    assert checked >= 2  # docs/cluster.md's first snippet and the README's
