"""``python -m grt.bench deform`` measures a population against ten calls of one in the same run (issue 40: a
new user measured 30-35 ms for a population of 10, slower than one call per candidate, against the documented
0.45 ms). Speed is the benchmark's business (docs/benchmarks.md); this checks that it measures both ways and that
a population deforms to exactly what one call per candidate gives."""

from __future__ import annotations

import json

import numpy as np
import pytest

from grt.bench import deform as bench
from grt.geometry.deform import ShapeDeformer


def test_the_bench_prints_the_population_against_ten_calls_of_one(capsys):
    bench.main(["--faces", "2000"])
    out = capsys.readouterr().out
    figures = json.loads(out.splitlines()[-1])
    for key in ("exact_population10_ms", "exact_10_calls_ms", "shape_population10_ms", "shape_10_calls_ms"):
        assert figures[key] > 0, key
    ratio = figures["exact_population10_ms"] / figures["exact_10_calls_ms"]  # of the rounded figures
    assert figures["population_vs_calls"] == pytest.approx(ratio, rel=0.05)
    assert "population of 10 in one call / ten calls of one" in out


def test_a_population_deforms_to_what_one_call_per_candidate_gives():
    mesh = bench.bench_mesh(2000)
    mesh.apply_scale(0.1)  # meters: a 10 cm vase
    handles, anchors = bench.pick_constraints(mesh)
    thetas = 0.02 * np.random.default_rng(1).standard_normal((6, len(handles), 3))
    for method in ("exact", "smooth"):
        deformer = ShapeDeformer(mesh, handles, anchors, method=method)
        population = deformer.vertices(thetas)
        assert population.shape == (6, len(mesh.vertices), 3)
        np.testing.assert_array_equal(population, np.stack([deformer.vertices(t) for t in thetas]))
