"""Canonical pi (sampling/msa/canonical.py): a function of C alone, whatever the solver's signs and
in-eigenspace rotations, equal across the exact and fast paths, and never ambiguous on the parity streams."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_path
from helpers.msa_windows import planar_window
from helpers.parity import MSA_NAME, STREAMS, load_stream, sampler_for, stream  # noqa: F401 (stream: a fixture)

from msa_slam.sampling.msa import exact, fast, terms
from msa_slam.sampling.msa.canonical import SIGN_ATOL, canonicalise
from msa_slam.sampling.msa.powerset import feasible_subsets, subsets_by_size


def spectrum_matrix(lam: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A symmetric C with eigenvalues lam and a random orthonormal eigenbasis Q (C = Q diag(lam) Q^T)."""
    q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((len(lam), len(lam))))
    return (q * lam) @ q.T, q


def canonical(lam: np.ndarray, vec: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    lam, vec = lam.copy(), vec.copy()
    err = canonicalise(lam, vec, len(lam), np.empty((len(lam) + 1, len(lam))))
    return lam, vec, err


def test_canonical_pairs_ignore_the_solvers_signs_and_rotations_in_an_eigenspace():
    lam = np.array([0.0, 0.5, 2.0, 2.0, 2.0, 7.0, 9.0])  # a triple eigenvalue at 2
    c, q = spectrum_matrix(lam, 1)
    rng = np.random.default_rng(2)
    rotation, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    other = q * rng.choice([-1.0, 1.0], len(lam))  # another solver: other signs, another basis of lam = 2
    other[:, 2:5] = other[:, 2:5] @ rotation
    assert np.allclose((other * lam) @ other.T, c)
    assert not np.allclose(other, q)
    lam_a, vec_a, err_a = canonical(lam, q)
    lam_b, vec_b, err_b = canonical(lam, other)
    np.testing.assert_allclose(vec_a, vec_b, atol=1e-12)
    np.testing.assert_allclose(lam_a, lam_b)
    assert np.isfinite(err_a) and np.isfinite(err_b)
    np.testing.assert_allclose((vec_a * lam_a) @ vec_a.T, c, atol=1e-12)  # still C's eigen-decomposition
    assert all(vec_a[np.argmax(np.abs(vec_a[:, j])), j] > 0 for j in range(len(lam)))


def test_near_equal_eigenvalues_form_one_cluster_with_their_mean():
    lam = np.array([1.0, 3.0, 3.0 * (1 + 1e-9), 5.0])
    _, q = spectrum_matrix(lam, 3)
    got, _, _ = canonical(lam, q)
    assert got[1] == got[2] == pytest.approx(3.0 * (1 + 5e-10), rel=1e-15)
    assert got[0] == 1.0 and got[3] == 5.0


def test_a_sign_tie_at_rounding_level_is_reported():
    vec = np.eye(3)
    vec[:, 0] = [0.6, -(0.6 - SIGN_ATOL), 0.0]  # the second component right at the tie's edge
    vec[2, 0] = np.sqrt(1 - vec[0, 0] ** 2 - vec[1, 0] ** 2)
    vec[:, 1] = np.cross(vec[:, 2], vec[:, 0])
    assert canonical(np.array([1.0, 2.0, 3.0]), vec)[2] == np.inf
    vec[:, 0] = [0.6, -(0.6 - 2 * SIGN_ATOL), 0.0]  # clearly outside the tie
    vec[2, 0] = np.sqrt(1 - vec[0, 0] ** 2 - vec[1, 0] ** 2)
    vec[:, 1] = np.cross(vec[:, 2], vec[:, 0])
    assert np.isfinite(canonical(np.array([1.0, 2.0, 3.0]), vec)[2])


def test_canonical_pi_is_invariant_where_the_reference_is_not(monkeypatch):
    """Flip the signs LAPACK returns: the reference's pi moves, the canonical one does not."""
    rng = np.random.default_rng(4)
    t = np.zeros((6, 3))
    t[:, 0] = np.cumsum(rng.uniform(0.5, 1.5, 6))
    flat = np.cumsum(rng.standard_normal((6, 40)), axis=0)
    values = {True: [], False: []}
    eigh = np.linalg.eigh
    for signs in (np.ones(6), np.array([1.0, -1, 1, -1, -1, 1])):
        monkeypatch.setattr(np.linalg, "eigh", lambda c, s=signs: (eigh(c)[0], eigh(c)[1] * s))
        for canonical_pi in (True, False):
            values[canonical_pi].append(terms.information(t, flat, canonical_pi))
    monkeypatch.setattr(np.linalg, "eigh", eigh)
    assert values[True][0] == pytest.approx(values[True][1], abs=1e-12)
    assert abs(values[False][0] - values[False][1]) > 1e-3


def test_batched_canonical_pi_equals_the_one_subset_definition():
    n = 8
    t, desc = planar_window(n)
    subsets = subsets_by_size(n)[3]
    dist, _ = exact.pairwise(t, desc)
    batched = exact._information(subsets, dist[0, subsets], desc, exact.ExactWorkspace(), True)
    one_by_one = [terms.information(t[s], desc[s], True) for s in subsets]
    assert batched.tolist() == one_by_one
    masks = feasible_subsets(dist, dist, 0.0, np.inf)[0]
    masks = masks[[bin(int(k)).count("1") == 5 for k in masks]]
    value, low, high = fast.information_rows(masks, dist, fast.gram(desc), 0, True, 2)  # the sampler's types
    np.testing.assert_allclose(value, one_by_one, atol=1e-9)
    assert (low <= value).all() and (value <= high).all() and (high - low < 1e-6).all()


def test_canonical_pi_has_no_ambiguous_window_on_the_parity_streams(stream, record_property):
    """Every window of the 24 configurations, fast path; reports the agreement with the reference."""
    name, poses, descriptors, _, expected = stream
    windows = agree = 0
    for config, keyframes in expected.items():
        if MSA_NAME.match(config):
            sampler = sampler_for(config, "fast", "canonical")
            agree += sampler.run(poses, descriptors) == keyframes
            windows += sampler.stats.window_optimisations
            assert sampler.stats.ambiguous == [], config
    assert windows > 0
    record_property("canonical_agreeing_with_reference", f"{agree} of 24")


def test_exact_and_fast_paths_choose_the_same_canonical_keyframes(stream):
    _, poses, descriptors, _, expected = stream
    configs = [c for c in expected if MSA_NAME.match(c)][::6]  # 4 of 24: both N and both neighbour counts
    for config in configs:
        assert sampler_for(config, "exact", "canonical").run(poses, descriptors) == sampler_for(
            config, "fast", "canonical"
        ).run(poses, descriptors), config


@pytest.mark.parametrize("m", [3, 10, 19])
def test_compiled_eigensolver_matches_lapack_on_random_and_degenerate_matrices(m):
    from msa_slam.sampling.msa.eigen import symmetric_eigh

    rng = np.random.default_rng(m)
    lam = np.sort(rng.uniform(0, 10, m))
    lam[1:3] = lam[1]  # a repeated eigenvalue
    for c in (spectrum_matrix(lam, m)[0], np.cov(rng.standard_normal((m, 2 * m)))):
        got_lam, got_vec = np.empty(m), c.copy()
        symmetric_eigh(got_vec, got_lam, np.empty(m), m)
        want_lam, want_vec = np.linalg.eigh(c)
        scale = np.abs(want_lam).max()
        np.testing.assert_allclose(got_lam, want_lam, atol=1e-13 * scale)
        np.testing.assert_allclose(got_vec.T @ got_vec, np.eye(m), atol=1e-13)
        np.testing.assert_allclose((got_vec * got_lam) @ got_vec.T, c, atol=1e-13 * scale)
        np.testing.assert_allclose(canonical(got_lam, got_vec)[1], canonical(want_lam, want_vec)[1], atol=1e-9)


@pytest.mark.parametrize("n", [3, 7, 11])
def test_streamed_candidates_are_the_constrained_power_set_in_order(n):
    rng = np.random.default_rng(n)
    t = np.zeros((n, 3))
    t[:, :2] = np.cumsum(rng.uniform(0.2, 1.5, (n, 2)), axis=0)
    dist, sim = exact.pairwise(t, rng.standard_normal((n, 5)))
    masks, rho = feasible_subsets(dist, sim, 0.5, 2.5)
    want = terms.constrained_power_set(t, 0.5, 2.5)
    got = [fast.mask_positions(int(k)) for k in masks]
    assert got == (want if len(masks) else [])
    assert rho.tolist() == [sum(sim[b, a] for a, b in zip(s, s[1:])) / (len(s) - 1) for s in got]


def test_candidate_batches_hold_one_size_each_and_cover_every_candidate():
    """The threads' work units: consecutive candidates of one size, at most `lanes` of them, in order."""
    rng = np.random.default_rng(5)
    n = 13
    t = np.zeros((n, 3))
    t[:, 0] = np.cumsum(rng.uniform(0.5, 1.5, n))
    dist, sim = exact.pairwise(t, rng.standard_normal((n, 8)))
    masks = feasible_subsets(dist, sim, 0.1, 3.0)[0]
    starts = fast.candidate_batches(masks, 32)
    sizes = np.array([bin(int(k)).count("1") for k in masks])
    assert starts[0] == 0 and starts[-1] == len(masks) and (np.diff(starts) > 0).all()
    assert (np.diff(starts) <= 32).all()
    for a, b in zip(starts[:-1], starts[1:]):
        assert len(set(sizes[a:b])) == 1
    full_or_last = [b - a == 32 or b == len(masks) or sizes[b] != sizes[a] for a, b in zip(starts[:-1], starts[1:])]
    assert all(full_or_last)  # a batch is cut short only where the size changes
    assert fast.candidate_batches(masks[:0], 32).tolist() == [0]


def test_thread_count_does_not_change_canonical_keyframes(monkeypatch):
    import numba

    monkeypatch.setattr(fast, "PARALLEL_FROM", 0)  # these windows are small: make them take the threaded path

    poses, descriptors = load_stream(shared_path("parity", "stream_s2_sc20x60.npz"))[:2] if STREAMS else (None, None)
    if poses is None:
        pytest.skip("parity vectors not available (../shared/parity)")
    runs = []
    for threads in (1, numba.config.NUMBA_NUM_THREADS):
        numba.set_num_threads(threads)
        try:
            sampler = sampler_for("msa_N10_nn2_a10_b1_l0.1_u5", "fast", "canonical")
            runs.append((sampler.run(poses, descriptors), sampler.stats.ambiguous))
        finally:
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    assert runs[0] == runs[1]


@pytest.mark.parametrize("size", [1e-160, 1e160])
def test_compiled_eigensolver_keeps_its_accuracy_at_extreme_scales(size):
    """QL's rotations use a plain square root (no hypot) after an exact power-of-two scaling of C:
    without that scaling, p * p + e * e underflows at 1e-160 and overflows at 1e160."""
    from msa_slam.sampling.msa.eigen import symmetric_eigh

    m = 9
    c = np.cov(np.random.default_rng(7).standard_normal((m, 2 * m))) * size
    got_lam, got_vec = np.empty(m), c.copy()
    symmetric_eigh(got_vec, got_lam, np.empty(m), m)
    want_lam, want_vec = np.linalg.eigh(c)
    assert np.isfinite(got_lam).all() and np.isfinite(got_vec).all()
    np.testing.assert_allclose(got_lam, want_lam, rtol=0, atol=1e-13 * np.abs(want_lam).max())
    np.testing.assert_allclose(canonical(got_lam, got_vec)[1], canonical(want_lam, want_vec)[1], atol=1e-9)


def test_serial_and_threaded_candidate_loops_give_identical_pi():
    """Small windows run on the calling thread, large ones on numba's threads (fast.PARALLEL_FROM):
    every candidate's value must not depend on which, nor on the thread count or the block split."""
    import numba

    rng = np.random.default_rng(11)
    n = 14
    t = np.zeros((n, 3))
    t[:, 0] = np.cumsum(rng.uniform(0.5, 1.5, n))
    desc = np.cumsum(rng.standard_normal((n, 32)), axis=0)
    dist, sim = exact.pairwise(t, desc)
    masks = feasible_subsets(dist, sim, 0.1, 3.0)[0]
    assert len(masks) > fast.PARALLEL_FROM
    serial = fast.information_rows_serial(masks, dist, fast.gram(desc), 0, True)
    assert np.isfinite(serial[0, [bin(int(k)).count("1") > 2 for k in masks]]).all()
    for threads, blocks in ((1, 3), (numba.config.NUMBA_NUM_THREADS, 16)):
        numba.set_num_threads(threads)
        try:
            threaded = fast.information_rows(masks, dist, fast.gram(desc), 0, True, blocks)
        finally:
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        assert np.array_equal(serial, threaded)


def lane_decomposition(mats: list[np.ndarray], count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """symmetric_eigh_lanes on the matrices, `count` at a time: eigenvalues, eigenvectors (rows), flags."""
    from msa_slam.sampling.msa.eigen import LANE_WORK, LANES, symmetric_eigh_lanes

    m = len(mats[0])
    values, vectors, flags = [], [], []
    for start in range(0, len(mats), count):
        batch = np.stack(mats[start : start + count], axis=-1)
        v = np.zeros((m, m, LANES))
        v[:, :, : batch.shape[-1]] = batch
        d, e, work = np.empty((m, LANES)), np.empty((m, LANES)), np.empty((LANE_WORK, LANES))
        symmetric_eigh_lanes(v, d, e, m, batch.shape[-1], work)
        for lane in range(batch.shape[-1]):
            values.append(d[:, lane].copy())
            vectors.append(v[:, :, lane].copy())
            flags.append(work[0, lane])
    return np.array(values), np.array(vectors), np.array(flags)


def test_lane_eigensolver_gives_each_matrix_its_own_values_whatever_the_other_lanes():
    """symmetric_eigh_lanes decomposes up to LANES matrices together: each matrix must get the same
    bits whether alone or among others (other sweep counts, an early finish, repeated eigenvalues, a
    tridiagonal that splits), accurate ones; a matrix whose reduction meets an exactly zero column
    (zeros, a diagonal) is flagged (it takes EISPACK's zero-column step; tests/test_msa_eigen.py)."""
    from msa_slam.sampling.msa.eigen import LANES

    rng = np.random.default_rng(21)
    for m in (3, 6, 10, 13, 19):
        mats = []
        for k in range(2 * LANES + 5):  # two full batches and a partial one
            x = rng.standard_normal((m, m + 2)) * 10.0 ** rng.uniform(-8, 8)
            mats.append(x @ x.T)
        lam = np.repeat(rng.uniform(0, 5, (m + 1) // 2), 2)[:m]  # repeated eigenvalues
        mats[3] = spectrum_matrix(np.sort(lam), m)[0]
        split = mats[8].copy()
        split[: m // 2, m // 2 :] = split[m // 2 :, : m // 2] = 1e-18 * np.abs(split).max()  # nearly two blocks:
        mats[8] = split  # QL's tridiagonal splits (negligible entries)
        mats[11] = np.zeros((m, m))
        mats[12] = np.diag(np.arange(m, dtype=float))
        together, vectors, flags = lane_decomposition(mats, LANES)
        alone, alone_vectors, alone_flags = lane_decomposition(mats, 1)
        assert np.array_equal(flags, alone_flags) and flags[11] != 0 and flags[12] != 0
        taken = flags == 0
        assert taken.sum() == len(mats) - 2
        assert np.array_equal(together[taken], alone[taken]) and np.array_equal(vectors[taken], alone_vectors[taken])
        for k, c in enumerate(mats):
            if not taken[k]:
                continue
            scale = np.abs(c).max()
            np.testing.assert_allclose(np.sort(together[k]), np.linalg.eigvalsh(c), atol=1e-13 * scale)
            np.testing.assert_allclose(vectors[k] @ vectors[k].T, np.eye(m), atol=1e-13)
            np.testing.assert_allclose((vectors[k].T * together[k]) @ vectors[k], c, atol=1e-13 * scale)


def test_batched_candidates_give_the_values_of_one_candidate_at_a_time():
    """The candidate loop decomposes same-size candidates together (full batches of LANES and the
    partial ones where the size changes): every candidate's pi and bounds must be those of
    information_gram on it alone."""
    from msa_slam.sampling.msa.eigen import LANES

    t, desc = planar_window(14, 32, 9)
    dist, sim = exact.pairwise(t, desc)
    masks = feasible_subsets(dist, sim, 0.1, 3.0)[0]
    gram = fast.gram(desc)
    batched = fast.information_rows_serial(masks, dist, gram, 0, True)
    scratch = np.empty(fast.scratch_size(len(t)))
    single = np.zeros_like(batched)
    sizes = []
    for i, mask in enumerate(masks):
        members = np.array(fast.mask_positions(int(mask)))
        sizes.append(len(members))
        if len(members) > 2:
            single[:, i] = fast.information_gram(members, len(members), dist, gram, scratch, 0, True)
    counts = np.bincount(sizes)[3:]
    assert counts.max() > LANES and (counts % LANES).max() > 0  # full batches and partial ones
    assert np.array_equal(batched, single)
