"""Measure the memory of one simulator worker once its task session is built (the figure behind
``grt.evaluators.pool.WORKER_MB``): ``PYTHONPATH=$PWD python scripts/worker_memory.py task=grasp policy=antipodal``.

Starts a :class:`grt.evaluators.pool.WorkerPool` of one worker for the composed ``run`` config's task and
policy, waits until the worker reports its session built, then prints the worker's RSS and PSS (from
``/proc/<pid>/smaps_rollup``) in MB, and closes it.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from hydra import compose, initialize_config_dir

from grt.config import plain
from grt.evaluators.pool import WorkerPool

CONF = Path(__file__).resolve().parents[1] / "conf"


def memory_mb(pid: int) -> dict[str, float]:
    """``{"rss": MB, "pss": MB}`` of process ``pid``."""
    out = {}
    for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("Rss", "Pss"):
            out[key.lower()] = int(value.split()[0]) / 1024
    return out


def main(overrides: list[str]) -> None:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="run", overrides=overrides)
    pool = WorkerPool(plain(cfg.task), plain(cfg.policy), workers=1)
    start = time.perf_counter()
    pool.start()
    worker = pool.workers[0]
    kind, payload = worker.conn.recv()
    if kind != "ready":
        raise SystemExit(f"the worker could not build its session:\n{payload}")
    time.sleep(1.0)
    mem = memory_mb(worker.proc.pid)
    print(f"{' '.join(overrides)}: worker ready in {time.perf_counter() - start:.1f} s, "
          f"RSS {mem['rss']:.0f} MB, PSS {mem['pss']:.0f} MB")
    pool.close()


if __name__ == "__main__":
    main(sys.argv[1:])
