"""The compiled decision (decision.py) chooses what eq. (8) in numpy (terms.score) chooses."""

from __future__ import annotations

import numpy as np
import pytest

from msa_slam.sampling.msa.decision import decide, minmax_bounds
from msa_slam.sampling.msa.terms import ScoreWeights, minmax, score


@pytest.mark.parametrize("seed", range(4))
def test_compiled_decision_equals_the_numpy_score_definition(seed):
    rng = np.random.default_rng(seed)
    for trial in range(200):
        count = int(rng.integers(2, 30))
        rho = rng.uniform(0, 2, count)
        pi = np.round(rng.uniform(0, 0.7, count), int(rng.integers(1, 4)))  # rounded: ties happen
        if trial % 6 == 0:
            rho[:] = rho[0]  # all equal: minmax gives ones
        weights = ScoreWeights(
            alpha=float(rng.choice([0.5, 1.0, 10.0])),
            beta=float(rng.choice([1.0, 2.0])),
            use_rho=trial % 4 != 0,
            use_pi=trial % 5 != 0,
        )
        scores = score(rho, pi, weights)
        want = int(np.argmin(scores))
        best, ambiguous, margin = decide(
            count, rho if weights.use_rho else None, pi if weights.use_pi else None, pi, pi, weights
        )
        assert best == want
        assert margin == float(np.min(np.delete(scores, want)) / scores[want] - 1.0)
        assert ambiguous or margin > 0  # a tie for the minimum is always ambiguous


def test_compiled_minmax_bounds_reduce_to_minmax_without_uncertainty():
    values = np.random.default_rng(5).uniform(0, 3, 50)
    low, high = minmax_bounds(values, values)
    assert np.array_equal(low, minmax(values)) and np.array_equal(high, minmax(values))
