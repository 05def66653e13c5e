"""Sampler API, registry, baselines and MSA behaviour on constructed streams."""

from __future__ import annotations

import re

import numpy as np
import pytest
from helpers.msa_windows import planar_window

from msa_slam.errors import InputError
from msa_slam.sampling import SAMPLERS, make_sampler, sampler_parameters
from msa_slam.sampling.baselines import histogram_entropy, spaciousness_threshold
from msa_slam.sampling.msa import ScoreWeights, optimise_window
from msa_slam.sampling.msa.powerset import subsets_by_size


def straight_line(n: int, step: float = 1.0) -> np.ndarray:
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n) * step
    return poses


def random_walk(n: int, seed: int = 0, dim: int = 32):
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :2, 3] = np.cumsum(rng.uniform(0.3, 1.2, (n, 2)), axis=0)
    descriptors = np.cumsum(rng.standard_normal((n, dim)), axis=0)
    return poses, descriptors


def test_registry_lists_all_paper_methods():
    assert set(SAMPLERS) == {"all", "constant", "entropy", "spaciousness", "msa"}
    assert sampler_parameters("msa")["window"] == 10
    assert sampler_parameters("constant") == {"distance": 1.0, "min_motion": 0.0, "min_rotation": 0.0}  # the gate


def test_unknown_sampler_name_lists_available():
    with pytest.raises(InputError, match="unknown sampler 'msaa'; available: all, constant"):
        make_sampler("msaa")


def test_unknown_parameter_lists_known_ones():
    with pytest.raises(InputError, match=r"unknown parameter\(s\) windw; it takes: window=10"):
        make_sampler("msa", windw=5)


@pytest.mark.parametrize(
    "name, params, fragment",
    [
        ("msa", {"window": 2}, "window=2 is not allowed; expected an integer >= 3"),
        ("msa", {"window": "abc"}, "window='abc' is not allowed; expected an integer >= 3"),
        ("msa", {"window": 9.5}, "window=9.5 is not allowed"),
        ("msa", {"mode": "quick"}, "mode='quick' is not allowed; expected one of exact, fast"),
        ("msa", {"alpha": 0}, "alpha=0 is not allowed; expected a finite number > 0"),
        ("msa", {"alpha": float("nan")}, "alpha=nan is not allowed; expected a finite number > 0"),
        ("msa", {"beta": float("inf")}, "beta=inf is not allowed; expected a finite number > 0"),
        ("msa", {"lambda_u": float("inf")}, "lambda_u=inf is not allowed; expected a finite number > 0"),
        ("msa", {"lambda_l": "0.1"}, "lambda_l='0.1' is not allowed; expected a finite number >= 0"),
        (
            "msa",
            {"lambda_l": 4.0, "lambda_u": 3.0},
            "lambda_l=4.0 > lambda_u=3.0 is not allowed; expected lambda_l <= lambda_u",
        ),
        ("msa", {"use_rho": "maybe"}, "use_rho='maybe' is not allowed; expected true or false"),
        ("msa", {"use_pi": 1}, "use_pi=1 is not allowed; expected true or false"),
        ("msa", {"neighbours": -1}, "neighbours=-1 is not allowed; expected an integer >= 0"),
        ("msa", {"neighbours": True}, "neighbours=True is not allowed"),
        ("constant", {"distance": -1}, "distance=-1 is not allowed; expected a finite number >= 0"),
        ("constant", {"distance": "abc"}, "distance='abc' is not allowed; expected a finite number >= 0"),
        ("entropy", {"bins": 1000}, "bins=1000 is not allowed; expected an integer >= 1 and <= 100"),
        ("entropy", {"max_distance": float("nan")}, "max_distance=nan is not allowed; expected a finite number > 0"),
        ("spaciousness", {"smoothing": 1.0}, "smoothing=1.0 is not allowed; expected a finite number >= 0 and < 1"),
    ],
)
def test_invalid_parameter_values(name, params, fragment):
    with pytest.raises(InputError, match=re.escape(f"sampler {name!r}: {fragment}")):
        make_sampler(name, **params)


def test_valid_parameter_values_are_normalised():
    sampler = make_sampler("msa", window=12.0, neighbours=2, alpha=10, use_rho=np.bool_(False))
    assert sampler.window_size == 12 and isinstance(sampler.window_size, int)
    assert sampler.weights == ScoreWeights(alpha=10.0, use_rho=False)


@pytest.mark.parametrize(
    "params, fragment",
    [
        (
            {"window": 30},
            "window=30: up to 2^29 - 2 = 536870910 candidates per window optimisation, more than the limit of 32766",
        ),
        ({"window": 200}, "window=200: up to 2^199 - 2 = about 10^59 candidates"),
        ({"window": 17}, "window=17: up to 2^16 - 2 = 65534 candidates"),
        ({"window": 16, "neighbours": 2}, "window=16 (+1 neighbour): up to 2^16 - 2 = 65534 candidates"),
    ],
)
def test_window_with_too_many_candidates_is_refused(params, fragment):
    with pytest.raises(InputError, match=re.escape(fragment)):
        make_sampler("msa", **params)


def test_largest_allowed_window_is_accepted():
    assert make_sampler("msa", window=16).window_size == 16
    assert make_sampler("msa", window=15, neighbours=2).window_size == 15
    assert make_sampler("msa", window=20, mode="fast", pi="canonical").window_size == 20


@pytest.mark.parametrize(
    "params, fragment",
    [
        (
            {"window": 21, "mode": "fast", "pi": "canonical"},
            "window=21: up to 2^20 - 2 = 1048574 candidates per window optimisation, more than the limit of 524286 "
            "(window + max(neighbours - 1, 0) <= 20)",
        ),
        ({"window": 20, "mode": "exact", "pi": "canonical"}, "window=20: up to 2^19 - 2 = 524286 candidates"),
        ({"window": 17, "mode": "fast"}, "up to 20 with mode='fast', pi='canonical'"),
        ({"pi": "lapack"}, "pi"),
    ],
)
def test_canonical_window_limit_and_pi_choice(params, fragment):
    with pytest.raises(InputError, match=re.escape(fragment)):
        make_sampler("msa", **params)


def test_window_of_twenty_runs_with_canonical_pi():
    poses, desc = random_walk(24)
    sampler = make_sampler("msa", window=20, mode="fast", pi="canonical")
    keyframes = sampler.run(poses, desc)
    assert sampler.stats.window_optimisations >= 1 and keyframes[0] == 0 and len(keyframes) > 1
    assert sampler.stats.candidates_evaluated > 2**15


def test_window_longer_than_the_stream_warns():
    poses, desc = random_walk(8)
    sampler = make_sampler("msa", window=10)
    with pytest.warns(UserWarning, match=r"window=10 is longer than the stream \(8 frames\)"):
        sampler.expect_frames(8)
    for pose, d in zip(poses, desc):
        sampler.push(pose, d)
    with pytest.warns(UserWarning, match="the window never filled"):
        sampler.finish()
    assert sampler.online_keyframes == [0]
    with pytest.warns(UserWarning, match="longer than the stream"):
        make_sampler("msa", window=10).run(poses, desc)


def test_stream_that_fills_the_window_does_not_warn(recwarn):
    poses, desc = random_walk(30)
    sampler = make_sampler("msa", window=8)
    sampler.run(poses, desc, flush=True)
    assert not [w for w in recwarn if issubclass(w.category, UserWarning)]


def test_constant_distance_on_a_straight_line():
    sampler = make_sampler("constant", distance=2.0)
    assert sampler.run(straight_line(10, 0.5)) == [0, 4, 8]


def test_all_samples_and_push_return_values():
    sampler = make_sampler("all")
    assert [sampler.push(p) for p in straight_line(3)] == [[0], [1], [2]]
    assert sampler.finish() == []


def test_histogram_entropy_of_uniform_and_single_cell_clouds():
    corners = np.array([[x, y, z] for x in (0, 9) for y in (0, 9) for z in (0, 9)], dtype=float)
    # 8 equally filled cells: -0.5 * 8 * (1/8) * log2(1/8) = 1.5
    assert histogram_entropy(corners) == pytest.approx(1.5)
    assert histogram_entropy(np.ones((5, 3))) == 0.0


def test_entropy_keyframe_on_scene_change_and_distance():
    rng = np.random.default_rng(1)
    spread = rng.uniform(-10, 10, (500, 3))
    compact = np.vstack([spread[:50], np.zeros((450, 3))])
    poses = straight_line(4, 1.0)
    sampler = make_sampler("entropy", threshold=0.05, max_distance=2.5)
    keyframes = sampler.run(poses, clouds=[spread, spread, compact, compact])
    assert keyframes == [0, 2]  # the cloud changed at frame 2; frame 3 is only 1 m further
    sampler = make_sampler("entropy", threshold=0.05, max_distance=2.5)
    assert sampler.run(straight_line(4, 1.0), clouds=[spread] * 4) == [0, 3]  # 3 m > 2.5 m


def test_spaciousness_threshold_bands():
    assert [spaciousness_threshold(s) for s in (20.0, 7.0, 4.0, 2.5)] == [3.0, 2.0, 1.0, 2.5]


def test_spaciousness_uses_threshold_of_smoothed_mean_range():
    cloud = np.array([[12.0, 0.0, 0.0]])  # mean range 12 > 10 -> 3 m threshold
    sampler = make_sampler("spaciousness")
    assert sampler.run(straight_line(8, 1.0), clouds=[cloud] * 8) == [0, 4]  # > 3 m strictly


def test_point_based_baselines_require_points():
    with pytest.raises(InputError, match="frame 0 has no point cloud"):
        make_sampler("entropy").push(np.eye(4))


def test_bad_pose_is_named():
    pose = np.eye(4)
    pose[0, 3] = np.nan
    with pytest.raises(InputError, match=r"^msa: frame 0 pose has NaN or infinite values$"):
        make_sampler("msa").push(pose, np.zeros(8))
    sheared = np.eye(4)
    sheared[0, 1] = 0.5
    with pytest.raises(InputError, match="not a rigid transform"):
        make_sampler("all").push(sheared)
    with pytest.raises(InputError, match="expected a 4x4 pose"):
        make_sampler("all").push(np.eye(3))


def test_descriptor_shape_change_is_named():
    sampler = make_sampler("msa")
    sampler.push(np.eye(4), np.zeros(8))
    with pytest.raises(InputError, match=r"frame 1 descriptor has shape \(9,\), earlier frames had \(8,\)"):
        sampler.push(np.eye(4), np.zeros(9))


def test_run_rejects_mismatched_lengths():
    with pytest.raises(InputError, match="10 poses but 9 descriptors"):
        make_sampler("msa").run(straight_line(10), np.zeros((9, 4)))


def test_candidate_enumeration_follows_itertools_order():
    groups = subsets_by_size(5)
    assert [g.shape for g in groups] == [(4, 2), (6, 3), (4, 4)]
    assert groups[1][:3].tolist() == [[0, 1, 2], [0, 1, 3], [0, 1, 4]]
    assert sum(len(g) for g in subsets_by_size(10)) == 2**9 - 2


def test_window_without_feasible_subset_falls_back_to_ends():
    t = np.zeros((5, 3))
    t[:, 0] = np.arange(5) * 10.0  # every step is beyond dmax
    for mode in ("exact", "fast"):
        result = optimise_window(t, np.eye(5), dmin=0.1, dmax=5.0, weights=ScoreWeights(), mode=mode)
        assert result.positions == (0, 4) and result.candidates == 1


def test_rho_only_prefers_dissimilar_consecutive_members():
    # members 1 and 2 are near-duplicates in descriptor space: without pi, MSA skips one of them
    t = np.zeros((5, 3))
    t[:, 0] = np.arange(5, dtype=float)
    desc = np.array([[0.0], [5.0], [5.01], [10.0], [15.0]])
    weights = ScoreWeights(use_pi=False)
    for mode in ("exact", "fast"):
        chosen = optimise_window(t, desc, 0.5, 3.0, weights, mode).positions
        assert not {1, 2} <= set(chosen)


def test_msa_selects_a_subset_and_counts_its_work():
    poses, desc = random_walk(120)
    sampler = make_sampler("msa", window=8)
    keyframes = sampler.run(poses, desc)
    assert keyframes[0] == 0 and keyframes == sorted(set(keyframes))
    assert 10 < len(keyframes) < 120
    stats = sampler.stats.as_dict()
    assert stats["frames"] == 120
    assert stats["window_optimisations"] == len(sampler.stats.optimisation_ms) > 5
    assert stats["candidates_evaluated"] >= stats["window_optimisations"]


def test_msa_push_reports_keyframes_when_windows_close():
    poses, desc = random_walk(60, seed=3)
    sampler = make_sampler("msa", window=8)
    reported = [k for p, d in zip(poses, desc) for k in sampler.push(p, d)]
    assert reported == sampler.keyframes


def test_finish_flushes_the_window_apart():
    poses, desc = random_walk(50, seed=2)
    sampler = make_sampler("msa", window=10)
    online = sampler.run(poses, desc)
    flushed = sampler.finish()
    assert sampler.online_keyframes == online
    assert sampler.flushed_keyframes == flushed and flushed
    assert all(k > online[-1] for k in flushed)
    assert sampler.keyframes == online + flushed
    with pytest.raises(RuntimeError, match="after finish"):
        sampler.push(poses[0], desc[0])


def test_fast_and_exact_agree_on_2d_descriptors():
    rng = np.random.default_rng(5)
    poses, _ = random_walk(80, seed=5)
    desc = np.abs(np.cumsum(rng.standard_normal((80, 20, 60)), axis=0))
    exact = make_sampler("msa", window=9).run(poses, desc)
    fast = make_sampler("msa", window=9, mode="fast").run(poses, desc)
    assert exact == fast


def test_ablations_change_the_selection():
    poses, desc = random_walk(150, seed=7)
    full = make_sampler("msa").run(poses, desc)
    no_rho = make_sampler("msa", use_rho=False).run(poses, desc)
    no_pi = make_sampler("msa", use_pi=False).run(poses, desc)
    assert no_rho != full or no_pi != full


def test_neighbours_bring_old_keyframes_into_the_window_at_revisits():
    # out along x, then back: at the return, old keyframes are nearby
    n = 80
    poses = np.tile(np.eye(4), (n, 1, 1))
    x = np.concatenate([np.arange(40), 39 - np.arange(40)]) * 0.8
    poses[:, 0, 3] = x
    poses[40:, 1, 3] = 0.3
    desc = np.stack([np.sin(x / 3.0 + k) for k in range(16)], axis=1)
    sampler = make_sampler("msa", window=8, neighbours=2)
    sampler.run(poses, desc)
    baseline = make_sampler("msa", window=8, neighbours=0).run(poses, desc)
    assert sampler.keyframes != baseline


@pytest.mark.parametrize("shape", [(48,), (6, 12)])
def test_batched_exact_equals_one_at_a_time_transcription(shape):
    from msa_slam.sampling.msa.terms import optimise_window_literal

    rng = np.random.default_rng(11)
    for trial in range(6):
        n = 7 + trial % 3
        t = np.zeros((n, 3))
        t[:, :2] = np.cumsum(rng.uniform(0.2, 1.0, (n, 2)), axis=0)
        desc = np.cumsum(rng.standard_normal((n, *shape)), axis=0)
        for weights in (ScoreWeights(), ScoreWeights(alpha=10.0), ScoreWeights(use_rho=False)):
            expected = optimise_window_literal(t, desc, 0.1, 2.5, weights)
            assert optimise_window(t, desc, 0.1, 2.5, weights, "exact") == expected


def test_msa_without_descriptor_is_named():
    sampler = make_sampler("msa")
    with pytest.raises(InputError, match="msa: frame 0 has no descriptor; this sampler needs descriptors"):
        sampler.push(np.eye(4))
    sampler.push(np.eye(4), np.ones(4))  # the refused frame was not counted: this one is frame 0
    assert sampler.stats.frames == 1 and sampler.keyframes == [0]


@pytest.mark.parametrize("descriptor, dtype", [(np.ones(4, complex), "complex128"), (np.array(["a", "b"]), "<U1")])
def test_descriptors_must_be_real_numbers(descriptor, dtype):
    with pytest.raises(InputError, match=f"msa: frame 0 descriptor must hold real numbers, got dtype {dtype}"):
        make_sampler("msa").push(np.eye(4), descriptor)


def test_a_window_that_never_fills_on_a_standing_stream_says_why():
    sampler = make_sampler("msa", window=5)
    for _ in range(20):  # twenty frames at one place: none joins the window
        sampler.push(np.eye(4), np.ones(4))
    with pytest.warns(
        UserWarning,
        match=r"window=5: the window never filled in 20 frames \(only 1 moved at least "
        r"0.01 m from the member before them\), so only frame 0",
    ):
        sampler.finish()


def test_ambiguity_of_exact_ties_and_clear_choices():
    poses = straight_line(40, 0.7)
    tie = make_sampler("msa", window=6, use_pi=False)
    tie.run(poses, np.zeros((40, 4)))  # all candidates have the same rho: rounding decides
    assert tie.stats.ambiguous_windows == tie.stats.window_optimisations > 0
    record = tie.stats.as_dict()
    assert record["ambiguous_frames"] == [a.frame for a in tie.stats.ambiguous]
    assert all(a.margin == 0.0 and len(a.members) >= 6 for a in tie.stats.ambiguous)
    poses, desc = random_walk(120)
    for mode in ("exact", "fast"):
        clear = make_sampler("msa", window=8, mode=mode)
        clear.run(poses, desc)
        assert clear.stats.ambiguous_windows == 0 and clear.stats.as_dict()["ambiguous_frames"] == []


def test_minmax_bounds_are_exact_without_uncertainty_and_widen_with_it():
    from msa_slam.sampling.msa.decision import minmax_bounds
    from msa_slam.sampling.msa.terms import minmax

    values = np.array([0.2, 0.5, 0.9, 0.3])
    low, high = minmax_bounds(values, values)
    np.testing.assert_allclose(low, minmax(values), atol=1e-15)
    np.testing.assert_allclose(high, minmax(values), atol=1e-15)
    assert minmax_bounds(np.ones(3), np.ones(3))[0].tolist() == [1.0, 1.0, 1.0]
    low, high = minmax_bounds(values - [0, 0, 0.3, 0], values)  # the maximum may drop to 0.6
    assert high[1] == pytest.approx(0.3 / 0.4) and low[1] == pytest.approx(0.3 / 0.7)
    assert minmax_bounds(np.zeros(2), np.ones(2)) == (pytest.approx([0, 0]), pytest.approx([1, 1]))


def test_decision_is_ambiguous_only_when_a_probe_can_reach_the_winner():
    from msa_slam.sampling.msa.decision import decision_margin

    rho = np.array([0.5, 0.5, 0.1])
    pi = np.array([0.8, 0.79, 0.0])  # with alpha = 10, candidate 0 wins by ~0.6 %
    score = (10 + (rho - 0.1) / 0.4) / (1 + pi / 0.8)
    ambiguous, margin = decision_margin(score, rho, pi, pi, pi, 10.0, 1.0, 0)
    assert not ambiguous and margin == pytest.approx(score[1] / score[0] - 1)
    sign_flip = pi + [0, 0.05, 0]  # a probe moved the runner-up's pi past the winner's
    assert decision_margin(score, rho, pi, pi, sign_flip, 10.0, 1.0, 0)[0]
    assert not decision_margin(score, rho, pi, pi, pi + [0, 0.001, 0], 10.0, 1.0, 0)[0]


def test_batched_terms_equal_the_one_subset_definitions():
    """exact.py's pi is bit-identical to terms.information; fast.py's agrees to rounding."""
    from msa_slam.sampling.msa import exact, fast, terms
    from msa_slam.sampling.msa.powerset import feasible_subsets

    n = 8
    t, desc = planar_window(n)
    subsets = subsets_by_size(n)[3]  # every subset of 5 members
    dist, _ = exact.pairwise(t, desc)
    batched = exact._information(subsets, dist[0, subsets], desc, exact.ExactWorkspace())
    one_by_one = [terms.information(t[s], desc[s]) for s in subsets]
    assert batched.tolist() == one_by_one
    masks = feasible_subsets(dist, dist, 0.0, np.inf)[0]
    masks = masks[[bin(int(k)).count("1") == 5 for k in masks]]
    gram_pi = fast.information_rows(masks, dist, fast.gram(desc), 0, False, 2)[0]  # the sampler's argument types
    np.testing.assert_allclose(gram_pi, one_by_one, atol=1e-6)


@pytest.mark.parametrize("pi", ["reference", "canonical"])
def test_fast_mode_runs_in_a_forked_child_after_the_parent_used_it(pi):
    """The parallel loop's thread pool (numba workqueue) must survive a fork of a process that used it."""
    import multiprocessing

    poses, desc = random_walk(60)
    parent = make_sampler("msa", window=13, mode="fast", pi=pi).run(poses, desc)
    with multiprocessing.get_context("fork").Pool(1) as pool:
        child = pool.apply(_run_fast_msa, (poses, desc, pi))
    assert child == parent


def _run_fast_msa(poses, desc, pi):
    return make_sampler("msa", window=13, mode="fast", pi=pi).run(poses, desc)
