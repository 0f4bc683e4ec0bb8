"""Whole-or-nothing file writes (bottom layer): the one atomic-write helper family of GRT.

A file is written to a temporary name beside it, flushed to disk, then renamed over the target
(atomic on POSIX), so a reader, a second process or Ctrl-C never sees half a file.
"""

from __future__ import annotations

import json
import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary name next to ``path`` to write to; renamed onto ``path`` when the block succeeds.

    The temporary name keeps ``path``'s suffix (writers such as ``trimesh.export``, ``np.savez`` and
    ``savefig`` pick the format by it) and is removed when the block raises.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.{secrets.token_hex(4)}.tmp{path.suffix}")
    try:
        yield tmp
        with open(tmp, "rb") as f:  # durable before it replaces the old version
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` whole or not at all."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json_atomic(path: str | Path, data, indent: int | None = 2) -> None:
    """Write ``data`` as JSON to ``path`` whole or not at all."""
    write_text_atomic(path, json.dumps(data, indent=indent) + "\n")
