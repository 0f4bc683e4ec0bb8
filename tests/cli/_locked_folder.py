"""A GRT app started in a folder another process holds: refused before it writes there.

Shared by the lock tests of ``grt.blueteam``, ``grt.evaluate`` and ``grt.select`` (``grt.run``'s, with a
second real run, are in ``tests/cli/test_run_faults.py``): the test process takes the folder's lock itself
(a real ``flock`` held by its PID, as a running app holds it), so the app is refused at once, before any
simulation.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

from grt.runfolder.lock import LOCK, acquire, release

ROOT = Path(__file__).resolve().parents[2]


def contents(folder: Path) -> dict[str, str]:
    """Every file and folder under ``folder`` (hidden ones too): a file's content hash, ``"dir"`` for a folder."""
    return {str(p.relative_to(folder)): "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*"))}


def refused_while_locked(module: str, folder: Path, *args: str) -> str:
    """Run ``python -m module *args`` while this process holds ``folder``'s lock; assert it is refused as
    ``grt.run`` is (exit code 2, one ``error:`` line naming this PID, no traceback) and that it changed
    nothing in the folder. Returns the line."""
    assert acquire(folder)
    try:
        before = contents(folder)
        assert (folder / LOCK).read_text().strip() == str(os.getpid())
        proc = subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, capture_output=True, text=True,
                              timeout=120, env={**os.environ, "WANDB_MODE": "disabled"})
        after = contents(folder)
    finally:
        release(folder)
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr + proc.stdout, proc.stderr[-3000:]
    errors = [line for line in proc.stderr.splitlines() if "error" in line.lower()]
    assert len(errors) == 1 and errors[0].startswith("error: "), proc.stderr[-3000:]
    assert f"{folder} is in use by another GRT process (PID {os.getpid()}," in errors[0], errors[0]
    assert after == before  # not a byte written, removed or changed: the lock file still holds this PID
    assert not (folder / LOCK).exists()  # released: the next command may use the folder
    return errors[0]
