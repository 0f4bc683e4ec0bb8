"""Episode seeds stay distinct at any count, and a run's first seeds never change with the count."""

from __future__ import annotations

import numpy as np

from grt.redteam import episode_seeds


def test_seeds_are_distinct_at_a_million_and_the_first_n_never_change():
    many = episode_seeds(0, 1_000_000)
    assert len(set(many)) == len(many) == 1_000_000 and all(0 <= s < 2**31 - 1 for s in many[:1000])
    plain = [int(s) for s in np.random.default_rng(0).integers(0, 2**31 - 1, size=23_400)]
    assert len(set(plain)) == 23_399  # the plain draws repeat a seed at trial 23,400 for seed 0
    assert episode_seeds(0, 23_399) == plain[:23_399] == many[:23_399]  # the counts that were distinct: as before
    assert episode_seeds(0, 40_000) == many[:40_000]
    for seed, n in ((42, 64), (7, 128), (1, 5000)):
        assert episode_seeds(seed, n) == [int(s) for s in np.random.default_rng(seed).integers(0, 2**31 - 1, size=n)]
