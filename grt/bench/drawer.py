"""Benchmark of the drawer evaluation: ``python -m grt.bench drawer [--trials N] [--workers W]``.

Measures, in one run, on the nominal handle with a policy (default: the shipped state policy):

* raw simulation speed: ``env.step`` calls per second of GRT-Drawer-v1 in this process, with the
  analytic reach-pinch-pull expert acting (one control step = 2 physics steps at 120 Hz);
* trials per second in this process (one session, no worker pool): the baseline;
* trials per second through :class:`grt.evaluators.sim.SimEvaluator` with ``W`` worker processes,
  after start-up, and its speed-up over the in-process baseline measured in the same run.

The last line printed is one JSON object with every figure.
"""

from __future__ import annotations

from grt.bench.insertion import episode_bench


def main(argv: list[str] | None = None) -> None:
    from grt.policies.drawer_expert import DrawerExpertPolicy

    episode_bench(argv, "drawer", "drawer_state", "drawer_handle", DrawerExpertPolicy, __doc__)


if __name__ == "__main__":
    main()
