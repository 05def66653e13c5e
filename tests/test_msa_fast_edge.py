"""Exact and fast modes on windows whose geometry makes numpy.gradient divide by zero."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from msa_slam.sampling.msa import ScoreWeights, optimise_window
from msa_slam.sampling.msa.terms import optimise_window_literal


@pytest.mark.parametrize("mode,pi", [("fast", "reference"), ("fast", "canonical"), ("exact", "reference")])
def test_members_equidistant_from_the_first_are_scored_like_the_one_subset_definition(mode, pi):
    """Positions 1 and 2 lie 1 m from position 0: candidates with both have a zero step in the distance
    along the path, numpy.gradient gives inf/nan and the reference clips C. The compiled path raised
    ZeroDivisionError (numba's Python division semantics) instead."""
    t = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]], float)
    desc = np.random.default_rng(0).standard_normal((5, 8))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # numpy.gradient's division by zero
        want = optimise_window_literal(t, desc, 0.5, 3.0, ScoreWeights(), pi == "canonical")
    got = optimise_window(t, desc, 0.5, 3.0, ScoreWeights(), mode, None, pi)
    assert got.positions == want.positions and got.candidates == want.candidates == 14
