"""How an insertion run's CrashShapes sit in the hand: the plug's tilt at rest, before the policy acts.

A deformed grip changes how the fingers' flat pads seat the plug, so the plug can hang tilted in the
hand and its tip lands millimetres off the hole. A policy that never observes the plug (the state
policy) cannot see this; one that does (the point-cloud policy) can. This measures it for the nominal
plug and the run's lowest-scoring candidates: the tilt (deg) after 40 control steps of a motionless
hand, on the run's first evaluation episodes::

    .venv/bin/python scripts/in_hand_tilt.py outputs/insertion/usb_plug/insertion_state/manual-topdm/<time> --top 10

Measured in experiments/table3_blueteam/log.md ("Why the state policy's CrashShapes are out of its reach").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


class NotInsertionError(ValueError):
    """The run is not an insertion run."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="an insertion red-team run folder")
    parser.add_argument("--top", type=int, default=10, help="lowest-scoring candidates to measure")
    parser.add_argument("--episodes", type=int, default=3, help="episodes per shape")
    parser.add_argument("--steps", type=int, default=40, help="control steps at rest before measuring")
    args = parser.parse_args()

    from grt.blueteam.core import load_run, name_of, run_geometry
    from grt.cli._common import exit_on_user_error
    from grt.outputs import crash_records
    from grt.redteam import episode_seeds
    from grt.tasks.insertion import InsertionSession

    with exit_on_user_error(NotInsertionError):
        run, records = load_run(args.run)
        if run.task["name"] != "insertion":
            raise NotInsertionError(f"{args.run} is a {run.task['name']} run: the in-hand tilt is measured for "
                                    "insertion runs")
        nominal, deformer, collision = run_geometry(run, run.cache_dir)
        session_cfg = {k: v for k, v in run.task["session"].items() if k != "_target_"}
        session_cfg["cloud_points"] = 0
        seeds = episode_seeds(int(run.budget.seed), args.episodes)
        with InsertionSession(policy=None, **session_cfg) as session:  # no policy: the hand is held still
            def tilts(mesh) -> list[float]:
                session.load_object(mesh, collision.parts(mesh))
                out = []
                for seed in seeds:
                    session.reset(seed, rebuild=True)
                    for _ in range(args.steps):
                        _, _, _, _, info = session.step(np.zeros(6, np.float32))
                    out.append(info["tilt_deg"])
                return out

            print(f"{'shape':<10} {'score':>6}  tilt at rest (deg), {args.episodes} episodes")
            base = tilts(nominal)
            print(f"{'nominal':<10} {'':>6}  {' '.join(f'{t:5.1f}' for t in base)}   mean {np.mean(base):.1f}")
            for rec in crash_records(records, args.top):
                t = tilts(deformer.meshes(np.asarray(rec["theta"])[None])[0])
                print(f"{name_of(rec):<10} {rec['score']:6.3f}  {' '.join(f'{x:5.1f}' for x in t)}   mean {np.mean(t):.1f}",
                      flush=True)


if __name__ == "__main__":
    main()
