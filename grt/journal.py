"""Crash-safe, append-only, tamper-evident record of every evaluated candidate (``journal.jsonl``).

One JSON object per line, flushed and fsync'ed as each candidate finishes, so killing a run at any
moment (even ``kill -9``) loses no finished evaluation. On reading, a truncated **last** line (the
write that was interrupted) is detected, reported and cut off.

A resume trusts the journal's scores (it replays them instead of simulating again), so each line
carries ``sha256``: the SHA-256 of the previous line's checksum and this record's canonical JSON (keys
sorted, no spaces, without ``sha256``). An edited score, a removed or reordered line, or a damaged
line anywhere is refused with its line number: the run's results would otherwise be rewritten from
numbers no simulation produced. Lines written before checksums existed load unchecked (a warning),
so old run folders keep working; once a checked line appears, every later line must be checked.

Lines are strict JSON (any JSON reader takes them): a NaN score (an implausible candidate, not
simulated) is written ``null`` and the line's ``nonfinite`` key says where, so a reload gives the NaN
back; lines of older journals with bare ``NaN`` still load and verify.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
from collections.abc import Callable
from pathlib import Path

from grt.errors import UserError

log = logging.getLogger("grt.journal")

CHECKSUM = "sha256"


class JournalError(UserError, RuntimeError):  # RuntimeError: what caught it before still does
    """The journal cannot be used as it is; the message names the line and the fix."""


def chain_checksum(previous: str, record: dict) -> str:
    """The checksum of ``record`` (without its own ``sha256``) chained to the previous line's checksum.

    Args:
        previous: hex checksum of the line before (``""`` for the first line).
        record: the journal record; a ``sha256`` key in it is ignored.

    Returns:
        64 hex characters.
    """
    body = {k: v for k, v in record.items() if k != CHECKSUM}
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(f"{previous}\n{canonical}".encode()).hexdigest()


NONFINITE = "nonfinite"  # where a line's NaN/inf numbers were: [[path, "nan" | "inf" | "-inf"], ...]


def strict(record: dict) -> dict:
    """``record`` as strict JSON can hold it: every NaN/inf number becomes ``null``, and the key
    :data:`NONFINITE` lists where they were (its path of keys and list indices, and the value as text), so
    :func:`restore` gives the record back exactly. A record of finite numbers is returned as it is."""
    found: list = []

    def walk(value, path):
        if isinstance(value, float) and not math.isfinite(value):
            found.append([path, "nan" if value != value else ("inf" if value > 0 else "-inf")])
            return None
        if isinstance(value, dict):
            return {k: walk(v, [*path, k]) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [walk(v, [*path, i]) for i, v in enumerate(value)]
        return value

    clean = walk(record, [])
    return {**clean, NONFINITE: found} if found else record


def restore(record: dict) -> dict:
    """The record :func:`strict` was given: its NaN/inf numbers back where :data:`NONFINITE` says."""
    for path, text in record.pop(NONFINITE, None) or []:
        node = record
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = float(text)
    return record


class Journal:
    """Read and append candidate records.

    Every record has at least ``iteration`` (0 for the nominal object, then ``1..T``), ``candidate``
    (index within its iteration) and ``score``. Records in :attr:`records` are the appended ones
    (without the ``sha256`` that only exists on disk).

    Args:
        path: the ``journal.jsonl`` file (created when missing).

    Raises:
        JournalError: a line (not the interrupted last one) is not JSON, not a GRT record, or fails
            its checksum.
    """

    REQUIRED = ("iteration", "candidate", "score")

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.records: list[dict] = []
        self._index: dict[tuple[int, int], dict] = {}
        self._head = ""  # checksum of the last line, chained into the next one
        self.recovered_truncated_line = False
        self.unchecked_lines = 0  # lines written before checksums existed
        if self.path.exists():
            self._load()

    def _load(self) -> None:
        raw = self.path.read_bytes()
        lines = raw.split(b"\n")
        complete, tail = lines[:-1], lines[-1]  # tail: bytes after the last newline
        offset, checked = 0, False
        for n, line in enumerate(complete, start=1):
            start, offset = offset, offset + len(line) + 1
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
            except ValueError as exc:  # bad JSON or bytes that are not UTF-8
                raise self._modified(n, start, f"not valid JSON: {exc}") from exc
            if not isinstance(rec, dict):
                raise self._modified(n, start, "not a JSON object")
            missing = [k for k in self.REQUIRED if k not in rec]
            if missing:
                raise JournalError(f"{self.path}: line {n} lacks {missing}; not a GRT journal record.")
            stored = rec.pop(CHECKSUM, None)
            expected = chain_checksum(self._head, rec)
            if stored is None and checked:
                raise self._modified(n, start, "its checksum was removed")
            if stored is not None and stored != expected:
                raise self._modified(n, start, "its checksum does not match its content or the line before")
            checked = checked or stored is not None
            self.unchecked_lines += stored is None
            self._head = expected
            self._add(restore(rec))
        if self.unchecked_lines:
            log.warning("%s: %d line(s) written before journals had checksums; loaded unchecked",
                        self.path, self.unchecked_lines)
        if tail.strip():
            # An interrupted write: the candidate was not finished. Cut it so appends stay valid.
            self.recovered_truncated_line = True
            with open(self.path, "r+b") as f:
                f.truncate(len(raw) - len(tail))

    def _modified(self, n: int, start: int, why: str) -> JournalError:
        """The one-line error for line ``n`` (starting at byte ``start``) and the way out."""
        return JournalError(
            f"journal line {n} was modified or corrupted ({why}): {self.path}. Its scores cannot be trusted "
            f"for a resume. Either keep the {n - 1} line(s) before it (`truncate -s {start} {self.path}`) and "
            "resume, which re-evaluates the candidates from that line on, or start a new run.")

    def append(self, record: dict) -> None:
        """Append one record (with its chained checksum) and make it durable before returning."""
        missing = [k for k in self.REQUIRED if k not in record]
        if missing:
            raise ValueError(f"journal record lacks {missing}")
        if CHECKSUM in record:
            raise ValueError(f"journal record must not carry {CHECKSUM!r}: the journal computes it")
        if NONFINITE in record:
            raise ValueError(f"journal record must not carry {NONFINITE!r}: the journal writes it")
        # Strict JSON (NaN written as null, where it was noted), checksummed as it will read back (tuples
        # as lists, keys as strings), so a reload verifies; lines of older journals hold bare NaN and load.
        on_disk = strict(record)
        as_read = json.loads(json.dumps(on_disk, allow_nan=False))
        checksum = chain_checksum(self._head, as_read)
        line = json.dumps({**on_disk, CHECKSUM: checksum}, separators=(",", ":"), allow_nan=False) + "\n"
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(line)
            f.flush()
            os.fsync(f.fileno())
        self._head = checksum
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


class InOrder:
    """Records finished in any order, passed on in order: ``done(k, record)`` keeps record ``k`` until
    records ``0..k-1`` are in, then hands each ready one to ``write`` (e.g. the journal's append and a
    progress bar), so a journal's order never depends on which worker finished first."""

    def __init__(self, write: Callable[[dict], None]):
        self.write, self.written, self._ready = write, [], {}

    def done(self, k: int, record: dict) -> None:
        self._ready[k] = record
        while len(self.written) in self._ready:
            record = self._ready.pop(len(self.written))
            self.write(record)
            self.written.append(record)
