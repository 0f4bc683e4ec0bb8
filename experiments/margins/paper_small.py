"""How far the paper's search can move the surface: the reach of its protocol, in mm per object.

The paper's CrashShapes come from TOPDM with σ = 0.001 unit-cube units, 10 candidates x 10 iterations, half
of the handles perturbed per candidate (appendix, lines 1062-1099), 2-5 VLM handles (3.8 on average, its
project page). Whatever the policy, no candidate of that search is farther from the nominal object than the
search's steps can carry it. This replays GRT's TOPDM (grt.optimizers.topdm, Algorithm 1 as written) with that
protocol twice: told random scores (a policy the shapes do not affect) and told minus each candidate's largest
handle displacement (a search that always keeps the most displaced candidates: the farthest it can go), 200
seeds each, for 4 handles. The largest handle displacement (unit cube) is turned into mm with each object's
largest extent (the unit cube's side). With smooth handles the largest surface displacement is about the
largest handle displacement (each handle moves a region as a whole), so these mm compare with a profile's sizes.

    python experiments/margins/paper_small.py   # writes paper_small.json and paper_small_mm.json here

``paper_small_mm.json`` is ``{object: mm}`` (the most, by object name as the runs' summaries give it; the stock
PushCube actor is ``actor``), the bands of ``python -m grt.report ... --margins-plot ... --small``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from grt.objects import get_object
from grt.optimizers.topdm import TOPDMOptimizer

SIGMA, POPULATION, ITERATIONS, HANDLES, SEEDS = 0.001, 10, 10, 4, 200
OBJECTS = ("mug", "bottle", "can", "usb_plug")


def reach(greedy: bool, seed: int) -> float:
    """The largest handle displacement (unit cube) of any candidate of one search."""
    opt = TOPDMOptimizer(HANDLES, POPULATION, SIGMA, seed)
    rng, most = np.random.default_rng(seed + 10_000), 0.0
    for _ in range(ITERATIONS):
        thetas = opt.ask()
        largest = np.linalg.norm(thetas, axis=-1).max(axis=-1)
        most = max(most, float(largest.max()))
        opt.tell(thetas, -largest if greedy else rng.random(POPULATION))
    return most


def main() -> None:
    out = {"protocol": {"sigma": SIGMA, "population": POPULATION, "iterations": ITERATIONS, "handles": HANDLES,
                        "seeds": SEEDS}}
    for name, greedy in (("random_scores", False), ("greedy", True)):
        values = np.array([reach(greedy, s) for s in range(SEEDS)])
        out[name] = {"median_unit": float(np.median(values)), "p95_unit": float(np.percentile(values, 95)),
                     "max_unit": float(values.max())}
    extents = {o: float(np.max(get_object(o).extents)) * 1000 for o in OBJECTS}
    extents["cube_4cm"] = 40.0  # PushCube's stock cube
    out["largest_extent_mm"] = extents
    out["reach_mm"] = {o: {"typical": round(out["random_scores"]["median_unit"] * e, 3),
                           "at_most": round(out["greedy"]["max_unit"] * e, 3)} for o, e in extents.items()}
    path = Path(__file__).with_name("paper_small.json")
    path.write_text(json.dumps(out, indent=1) + "\n")
    bands = {("actor" if o == "cube_4cm" else o): v["at_most"] for o, v in out["reach_mm"].items()}
    path.with_name("paper_small_mm.json").write_text(json.dumps(bands, indent=1) + "\n")
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
