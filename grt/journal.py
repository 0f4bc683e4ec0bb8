"""Crash-safe, append-only record of every evaluated candidate (``journal.jsonl``).

One JSON object per line, flushed and fsync'ed as each candidate finishes, so killing a run at any
moment (even ``kill -9``) loses no finished evaluation. On reading, a truncated **last** line (the
write that was interrupted) is detected, reported and cut off; a corrupt line anywhere else means the
file was edited or damaged, and is an error that names the line.
"""

from __future__ import annotations

import json
import os
from pathlib import Path


class JournalError(RuntimeError):
    """The journal cannot be used as it is; the message names the line and the fix."""


class Journal:
    """Read and append candidate records.

    Every record has at least ``iteration`` (0 for the nominal object, then ``1..T``), ``candidate``
    (index within its iteration) and ``score``.

    Args:
        path: the ``journal.jsonl`` file (created when missing).
    """

    REQUIRED = ("iteration", "candidate", "score")

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.records: list[dict] = []
        self._index: dict[tuple[int, int], dict] = {}
        self.recovered_truncated_line = False
        if self.path.exists():
            self._load()

    def _load(self) -> None:
        raw = self.path.read_bytes()
        lines = raw.split(b"\n")
        complete, tail = lines[:-1], lines[-1]  # tail: bytes after the last newline
        for n, line in enumerate(complete, start=1):
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
            except json.JSONDecodeError as exc:
                raise JournalError(f"{self.path}: line {n} is not valid JSON ({exc}); the journal is "
                                   "corrupted. Remove that line (its candidate will be re-evaluated) "
                                   "or start a new run.") from exc
            missing = [k for k in self.REQUIRED if k not in rec]
            if missing:
                raise JournalError(f"{self.path}: line {n} lacks {missing}; not a GRT journal record.")
            self._add(rec)
        if tail.strip():
            # An interrupted write: the candidate was not finished. Cut it so appends stay valid.
            self.recovered_truncated_line = True
            with open(self.path, "r+b") as f:
                f.truncate(len(raw) - len(tail))

    def append(self, record: dict) -> None:
        """Append one record and make it durable before returning."""
        missing = [k for k in self.REQUIRED if k not in record]
        if missing:
            raise ValueError(f"journal record lacks {missing}")
        line = json.dumps(record, separators=(",", ":"), allow_nan=True) + "\n"
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(line)
            f.flush()
            os.fsync(f.fileno())
        self._add(record)

    def _add(self, record: dict) -> None:
        self.records.append(record)
        self._index[(record["iteration"], record["candidate"])] = record

    def get(self, iteration: int, candidate: int) -> dict | None:
        """The record of one candidate, or ``None`` if it was not evaluated yet."""
        return self._index.get((iteration, candidate))

    def iteration(self, iteration: int) -> dict[int, dict]:
        """``{candidate: record}`` of one iteration."""
        return {r["candidate"]: r for r in self.records if r["iteration"] == iteration}

    def __len__(self) -> int:
        return len(self.records)
