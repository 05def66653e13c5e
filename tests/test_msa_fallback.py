"""MSA windows whose distance bounds admit no candidate (the reference's fallback to the first and last member)
are counted in `stats.fallback_windows`, with one warning once they are most windows so far."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

from msa_slam.sampling import make_sampler
from msa_slam.sampling.msa import ScoreWeights
from msa_slam.sampling.msa.terms import WindowResult
from msa_slam.sampling.msa.window import fell_back, optimise_window


def walk(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A planar walk of steps about 1.2 m long with random-walk descriptors."""
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :2, 3] = np.cumsum(rng.uniform(0.3, 1.2, (n, 2)), axis=0)
    return poses, np.cumsum(rng.standard_normal((n, 16)), axis=0)


@pytest.mark.parametrize("mode", ["exact", "fast"])
def test_tiny_bounds_make_every_window_fall_back_and_warn(mode):
    poses, desc = walk(60)
    sampler = make_sampler("msa", window=6, lambda_l=0.001, lambda_u=0.01, mode=mode)  # dmax ~ 1 cm, steps ~ 1 m
    with pytest.warns(UserWarning) as caught:  # during the stream: a caller need not finish() it to be told
        sampler.run(poses, desc)
    told = [str(w.message) for w in caught if "windows so far" in str(w.message)]
    assert len(told) == 1 and re.fullmatch(
        r"msa: 3 of the 3 windows so far had no subset whose consecutive members "
        r"lie within the distance bounds \(last \[0\.001\d*, 0\.01\d*\] m .*"
        r"check lambda_l=0\.001 and lambda_u=0\.01",
        told[0],
    ), told
    online = sampler.stats.window_optimisations
    assert online > 3 and sampler.stats.fallback_windows == online
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sampler.finish()  # the flush window falls back too, without a second warning
    stats = sampler.stats.as_dict()
    assert stats["fallback_windows"] == stats["window_optimisations"] == online + 1
    assert stats["candidates_evaluated"] == online + 1  # one candidate each: the first and last member


@pytest.mark.parametrize("mode", ["exact", "fast"])
def test_usual_bounds_count_no_fallback_and_do_not_warn(mode):
    poses, desc = walk(60)
    sampler = make_sampler("msa", window=6, mode=mode)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sampler.run(poses, desc, flush=True)
    assert sampler.stats.window_optimisations > 3
    assert sampler.stats.as_dict()["fallback_windows"] == 0


def test_two_fallback_windows_are_counted_without_a_warning():
    poses, desc = walk(11)
    sampler = make_sampler("msa", window=6, lambda_l=0.001, lambda_u=0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sampler.run(poses, desc, flush=True)
    assert sampler.stats.fallback_windows == sampler.stats.window_optimisations == 2


def test_a_lone_feasible_first_last_pair_is_not_a_fallback():
    translations = np.array([[0.0, 0, 0], [0.1, 0, 0], [2.0, 0, 0]])  # only (0, 2) can be 1-3 m apart
    descriptors = np.eye(3)
    chosen = optimise_window(translations, descriptors, 1.0, 3.0, ScoreWeights())
    forced = optimise_window(translations, descriptors, 1.0, 1.5, ScoreWeights())
    assert chosen == forced == WindowResult((0, 2), 1)  # the optimisers report both alike
    assert not fell_back(chosen, translations, 1.0, 3.0)
    assert fell_back(forced, translations, 1.0, 1.5)


def test_sample_warns_once_without_flush_and_not_for_its_kernel_warm_up(tmp_path):
    from typer.testing import CliRunner

    from msa_slam.cli import app
    from msa_slam.io.poses import write_poses

    poses, desc = walk(40)
    write_poses(tmp_path / "poses.txt", poses)
    np.save(tmp_path / "desc.npy", desc)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = CliRunner().invoke(
            app,
            [
                "sample",
                "--poses",
                str(tmp_path / "poses.txt"),
                "--descriptors",
                str(tmp_path / "desc.npy"),
                "-p",
                "window=6",
                "-p",
                "lambda_l=0.001",
                "-p",
                "lambda_u=0.01",
                "--out",
                str(tmp_path / "out"),
                "-q",
            ],
        )
    assert result.exit_code == 0, result.output
    assert len([w for w in caught if "windows so far had no subset" in str(w.message)]) == 1
