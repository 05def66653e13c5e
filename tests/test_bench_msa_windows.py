"""benchmarks/bench_msa_windows.py: its rows (which (N, pi, mode) the sampler refuses), the keyframe agreement and
the table over seeds, on hand-made run values (the runs themselves are the pipeline's, tested elsewhere)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.benchmarks import loaded_benchmark


@pytest.fixture(scope="module")
def bench():
    yield from loaded_benchmark("bench_msa_windows")


def test_rows_modes_and_refusals_come_from_the_sampler(bench):
    rows = {v.key: v for v in bench.variants([10, 16, 20], exact_up_to=10)}
    assert set(rows) == {
        (10, "reference", "exact"),
        (10, "reference", "fast"),
        (10, "canonical", "exact"),
        (10, "canonical", "fast"),
        (16, "reference", "fast"),
        (16, "canonical", "fast"),
        (20, "reference", "fast"),
        (20, "canonical", "fast"),
    }
    refused = {k for k, v in rows.items() if v.refused}
    assert refused == {(20, "reference", "fast")}  # the neighbours setting keeps N=20 canonical fast accepted
    assert "524286 candidates" in rows[20, "reference", "fast"].refused


def test_jaccard(bench):
    assert bench.jaccard_pct([0, 5, 9], [0, 5, 9]) == 100.0
    assert bench.jaccard_pct([0, 5, 9], [0, 6]) == pytest.approx(100 / 4)
    assert bench.jaccard_pct([], []) == 100.0


def _values(bench, keyframes: list[int], improvement: float) -> dict:
    """One seed's run values: every column 1 except keyframes and the ATE improvement."""
    row = {key: 1.0 for key, _, _ in bench.COLUMNS}
    return {**row, "keyframes": float(len(keyframes)), "improvement_t_pct": improvement, "keyframe_frames": keyframes}


def _column(bench, row: str, header: str) -> str:
    labels = [h for _, h, _ in bench.COLUMNS]
    return row.split(" | ")[3 + labels.index(header)]


def test_table_mean_std_jaccard_and_na(bench):
    base, big = bench.Variant(10, "reference", "exact"), bench.Variant(16, "canonical", "fast")
    refused = bench.Variant(20, "reference", "fast", refused="too many candidates")
    failed = bench.Variant(20, "canonical", "fast")
    runs = {
        base.key: {0: _values(bench, [0, 2, 4], 10.0), 1: _values(bench, [0, 3], 20.0)},
        big.key: {0: _values(bench, [0, 4], 30.0), 1: _values(bench, [0, 3], 50.0)},
    }
    text = bench.table_markdown([base, big, refused, failed], runs, [0, 1], {failed.key: "seed 0: boom"})
    base_row, big_row, refused_row, failed_row = text.splitlines()[2:]
    assert _column(bench, base_row, "t. ATE impr. %") == "15.0 ± 7.1"  # mean and sample std of 10 and 20
    assert _column(bench, base_row, "kf Jaccard vs N=10 ref. %") == "100.0 ± 0.0"
    # seed 0: {0,4} vs {0,2,4} -> 2/3; seed 1: identical -> 100 %
    assert _column(bench, big_row, "kf Jaccard vs N=10 ref. %") == "83.3 ± 23.6"
    assert _column(bench, refused_row, "keyframes") == "n/a: too many candidates"
    assert _column(bench, failed_row, "keyframes") == "n/a: seed 0: boom"


def test_table_one_seed_has_no_std_and_a_missing_baseline_seed_is_na(bench):
    big = bench.Variant(16, "canonical", "fast")
    text = bench.table_markdown([big], {big.key: {0: _values(bench, [0, 4], 30.0)}}, [0])
    row = text.splitlines()[2]
    assert _column(bench, row, "t. ATE impr. %") == "30.0"
    assert _column(bench, row, "kf Jaccard vs N=10 ref. %") == "n/a"


def test_chance_jaccard_matches_random_sets(bench):
    rng = np.random.default_rng(0)
    n, k = 1000, 430
    draws = [bench.jaccard_pct(rng.choice(n, k, replace=False), rng.choice(n, k, replace=False)) for _ in range(200)]
    assert bench.chance_jaccard_pct(k, n) == pytest.approx(np.mean(draws), abs=0.5)
