"""Repetitions over world seeds: spread, ranks, paired-test verdicts and the `compare --seeds` checks."""

from __future__ import annotations

import pytest
from helpers.metrics import seed_row
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.errors import InputError
from msa_slam.evaluation.spread import paired_verdict, seed_ranks, spreads, without_rounding
from msa_slam.experiments.seeds import SEED_METRICS, parse_seeds, seed_markdown, seed_summary, seeded_datasets


def test_ranks_follow_the_metric_direction_and_skip_missing_values():
    values = {"a": 3.0, "b": 1.0, "c": None, "d": 3.0}
    assert seed_ranks(values, higher_is_better=True) == {"a": 1, "b": 3, "c": None, "d": 1}
    assert seed_ranks(values, higher_is_better=False) == {"a": 2, "b": 1, "c": None, "d": 2}


def test_spread_is_the_sample_std_over_available_seeds():
    out = spreads([{"msa": 1.0, "all": 5.0}, {"msa": 3.0, "all": None}], higher_is_better=True)
    assert out["msa"].mean == 2.0 and out["msa"].std == pytest.approx(2**0.5)
    assert out["all"].mean == 5.0 and out["all"].std is None and out["all"].ranks == [1, None]


def test_paired_verdicts():
    seeds = [0, 1, 2, 3]
    # MSA ahead by 10 +- 1 on worlds that differ by 50: beyond the spread of the differences
    msa, base = [60.0, 11.0, 35.0, 85.0], [49.0, 2.0, 24.0, 76.0]
    assert paired_verdict(msa, base, True, seeds).verdict.startswith("better, beyond the seed spread (p")
    assert paired_verdict(msa, base, False, seeds).verdict.startswith("worse, beyond")
    # differences of both signs: within the spread
    assert paired_verdict([1.0, 2.0, 3.0, 4.0], [2.0, 1.0, 4.0, 3.0], True, seeds).verdict.startswith("within")
    assert paired_verdict([1.0, 2.0], [0.0, 1.0], True, [0, 1]).verdict == (
        "n/a: 2 seed(s), the paired test needs at least 3"
    )
    assert paired_verdict([1.0, None, 3.0], [0.0, 1.0, 2.0], True, [0, 1, 2]).verdict == (
        "n/a: a value is n/a on seed(s) 1 (that seed's notes say why)"
    )
    assert paired_verdict([1.0, 2.0, 3.0], [1.0, 2.0, 3.0], True, [0, 1, 2]).verdict == "no difference on any seed"
    # no loop closed by either (simulated KITTI-09): improvements of +-1e-11 % are the optimiser's rounding
    rounding = paired_verdict([6.3e-12, -1.3e-12, -2.2e-12], [1.7e-12, 4.6e-13, -3.1e-12], True, [0, 1, 2])
    assert rounding.verdict == "no difference on any seed" and rounding.p is None
    assert (rounding.mean_difference, rounding.std_difference, rounding.sign) == (0.0, 0.0, 0)
    assert rounding.text() == "mean difference 0.0 ± 0.0 over 3 pair(s), p n/a (no difference on any seed)"
    # a pair that differs by rounding alone counts as equal (0.0), the others as they are
    assert without_rounding(50.0 + 1e-12, 50.0) == 0.0 and without_rounding(50.1, 50.0) == pytest.approx(0.1)
    mixed = paired_verdict([1.0 + 1e-13, 2.0, 3.0], [1.0, 1.0, 1.0], True, [0, 1, 2])
    assert mixed.mean_difference == pytest.approx(1.0) and mixed.p is not None
    # no variance: no p-value, and why; every seed agrees on the side
    same = paired_verdict([2.0, 3.0, 4.0], [1.0, 2.0, 3.0], False, [0, 1, 2])
    assert (same.sign, same.p, same.std_difference) == (-1, None, 0.0)
    assert same.verdict == "worse by the same amount on every seed (no variance: no p-value)"
    one = paired_verdict([2.0], [1.0], True, [0])
    assert one.std_difference is None and one.verdict == "n/a: 1 seed(s), the paired test needs at least 3"
    assert paired_verdict([1e-6, 2e-6, 4e-6], [0.0, 0.0, 0.0], True, [0, 1, 2]).p is not None
    # a p-value under 0.001 prints as such, not as p=0.000
    far = paired_verdict([10.0, 20.0, 30.0, 40.0], [0.0, 10.001, 20.0, 29.999], True, seeds)
    assert far.p < 0.001 and far.verdict == "better, beyond the seed spread (p<0.001)"


def test_seed_summary_reports_mean_std_ranks_and_verdicts():
    rows = {
        s: [
            seed_row("all", improvement_t_pct=10.0 + 20 * s, keyframes=100),
            seed_row("msa", improvement_t_pct=12.0 + 20 * s + 0.1 * s, keyframes=40),
        ]
        for s in range(3)
    }
    summary = seed_summary(rows)
    entry = summary.metrics["improvement_t_pct"]
    assert entry.methods["msa"].ranks == [1, 1, 1] and entry.methods["all"].mean == 30.0
    assert entry.msa_vs["all"].verdict.startswith("better, beyond the seed spread")
    assert summary.metrics["keyframes"].msa_vs == {}  # no direction: no test
    text = seed_markdown(summary)
    assert "| msa | 32.100 ± 20.100 |" not in text and "| msa | 32.1 ± 20.1 |" in text
    assert "| all | better, beyond the seed spread" in text and "paired t-test" in text


def test_seed_table_gives_each_metric_one_number_of_decimals():
    rows = {s: [seed_row("msa", ate_after_m=9.5 + s, rpe_pct=0.5 + s, keyframes=40 + s)] for s in range(3)}
    text = seed_markdown(seed_summary(rows))
    # ATE crosses 10 m between seeds yet keeps 3 decimals; counts (a mean over seeds) take 1
    assert "| 10.500 ± 1.000 |" in text and "| 1.500 ± 1.000 |" in text and "| 41.0 ± 1.0 |" in text
    assert "100-800" not in text  # each seed's comparison.md names the segment lengths its trajectory covers


def test_seed_table_says_why_a_value_is_n_a_or_has_no_spread():
    rows = {
        s: [
            seed_row("all", pr_auc=None, ate_after_m=1.0 if s == 0 else None),
            seed_row("msa", pr_auc=0.9, ate_after_m=2.0 + s),
        ]
        for s in range(3)
    }
    text = seed_markdown(seed_summary(rows))
    assert "| all | n/a¹ | n/a¹ | 1.000² |" in text
    assert "¹ n/a: the value is n/a on every seed" in text and "² known on one seed only" in text
    assert (
        "| all | n/a, n/a, n/a | n/a, n/a, n/a | 1, n/a, n/a |" in text
        and "Ranks: n/a where that seed has no value" in text
    )
    full = seed_markdown(seed_summary({s: [seed_row("msa", **{k: 1.0 + s for k in SEED_METRICS})] for s in range(3)}))
    assert "¹" not in full and "²" not in full and "Ranks: n/a" not in full


def test_seeds_are_parsed_and_only_simulated_data_takes_them():
    assert parse_seeds("0, 1,2") == [0, 1, 2]
    for bad in ("0,x", "1,1", "-1", ""):
        with pytest.raises(InputError, match="--seeds"):
            parse_seeds(bad)
    assert seeded_datasets("sim:test", [0, 2]) == ["sim:test,seed=0", "sim:test,seed=2"]
    with pytest.raises(InputError, match="not simulated; world seeds exist only for sim: datasets"):
        seeded_datasets("/data/kitti/00", [0, 1])
    with pytest.raises(InputError, match="already sets seed="):
        seeded_datasets("sim:kitti-05,seed=3", [0, 1])


def test_compare_refuses_seeds_on_real_data_before_any_work(tmp_path):
    folder = tmp_path / "seq"
    folder.mkdir()
    result = CliRunner().invoke(
        app, ["compare", "--dataset", str(folder), "--seeds", "0,1,2", "--out", str(tmp_path / "out")]
    )
    assert isinstance(result.exception, InputError) and "not simulated" in str(result.exception)
    assert not (tmp_path / "out").exists()


def test_grid_table_reports_the_spread_over_seeds():
    from msa_slam.experiments.report import table2_markdown
    from msa_slam.experiments.rows import METRICS, CellRow

    def row(method: str, seed: int, impr: float) -> CellRow:
        values = {
            **dict.fromkeys(METRICS),
            "keyframes": 10,
            "improvement_t_pct": impr,
            "improvement_r_pct": 1.0,
            "f1_max": 0.5,
            "memory_mib": 1.0,
            "memory_vs_reference_pct": 100.0,
            "time_s": 1.0,
        }
        reasons = {"backend_p99_ms": "not timed", "fps": "not timed"}
        return CellRow(f"c{seed}", "batch", "sim:test", "scan_context", method, method, seed, "", values, reasons)

    rows = [row("all", s, 10.0 * s) for s in range(3)] + [row("msa", s, 10.0 * s + 5 + 0.1 * s) for s in range(3)]
    text = table2_markdown(rows)
    assert "| msa | 10 ± 0 | 15.1 ± 10.1 % |" in text  # sample std (ddof 1) over the 3 seeds
    assert "Spread over seeds:" in text and "| all | better, beyond the seed spread" in text
    assert "Spread over seeds:" not in table2_markdown([r for r in rows if r.seed == 0])
    assert "- frames/s, back-end p99 n/a (every method and seed): not timed" in text  # n/a with its reason
