"""The front end's downsampled frame clouds: each frame's scan downsampled as the keyframe store would, cached by
the scans' identity and voxel size, and a back end filled from them stores the same clouds as one that reads
and downsamples the scans itself."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest
from helpers.metrics import metrics_json

from msa_slam.backend import PoseGraph
from msa_slam.io.cache import pipeline_cache
from msa_slam.pipeline import make_config, prepare_frontend, run
from msa_slam.registration import KeyframeCloudStore, downsample
from msa_slam.registration.cloud_cache import cloud_key
from msa_slam.slam import build_backend


@pytest.fixture(scope="module")
def config(sequence, odometry_file, tmp_path_factory):
    cache = tmp_path_factory.mktemp("frame-clouds-cache")
    return make_config(dataset=str(sequence), odometry=str(odometry_file), cache_dir=str(cache), sampler="msa")


@pytest.fixture(scope="module")
def frontend(config):
    return prepare_frontend(config)


def test_frame_clouds_are_the_scans_downsampled(frontend, config):
    clouds = frontend.clouds
    assert len(clouds) == len(frontend) and clouds.voxel_size == config.verifier.voxel_size
    for i in (0, len(frontend) // 2, len(frontend) - 1):
        expected = downsample(frontend.sequence[i].points, config.verifier.voxel_size)
        got = clouds[i]
        assert got.dtype == np.float32 and np.array_equal(got, expected)
        assert got.flags.owndata  # a copy the keyframe store owns, not a view of the memory-mapped entry
        assert got.strides == expected.strides


def test_frame_clouds_come_from_the_cache_unless_the_voxel_size_changes(frontend, config):
    again = prepare_frontend(config)
    assert again.cached["clouds"] and not frontend.cached["clouds"]
    assert np.array_equal(again.clouds.points, frontend.clouds.points)
    assert np.array_equal(again.clouds.offsets, frontend.clouds.offsets)
    coarser = config.model_copy(update={"verifier": config.verifier.model_copy(update={"voxel_size": 1.0})})
    other = prepare_frontend(coarser)
    assert not other.cached["clouds"] and other.clouds.voxel_size == 1.0
    assert len(other.clouds.points) < len(frontend.clouds.points)


def test_a_damaged_entry_is_recomputed_with_a_warning(frontend, config, caplog):
    key = cloud_key(frontend.sequence, config.verifier.voxel_size)
    entry = pipeline_cache(config.cache_dir) / f"frame-clouds-{key}.npy"
    original = entry.read_bytes()
    try:
        entry.write_bytes(original[: len(original) // 2])  # truncated
        with caplog.at_level(logging.WARNING):
            again = prepare_frontend(config)
        assert not again.cached["clouds"] and f"ignoring {entry}" in caplog.text
        assert np.array_equal(again.clouds.points, frontend.clouds.points)
    finally:
        entry.write_bytes(original)


def test_a_back_end_filled_from_frame_clouds_stores_what_it_would_downsample(frontend, config):
    """Same keyframes, loops, clouds and map with the front end's clouds as with the scans read again."""
    with_clouds = run(config, frontend)
    without = run(config, replace(frontend, clouds=None))
    assert np.array_equal(with_clouds.keyframes, without.keyframes)
    assert [(c.query, c.match, c.accepted) for c in with_clouds.loops] == [
        (c.query, c.match, c.accepted) for c in without.loops
    ]
    assert np.array_equal(with_clouds.map_points, without.map_points)
    assert metrics_json(with_clouds)["memory_bytes"] == metrics_json(without)["memory_bytes"]


def test_frame_clouds_of_another_voxel_size_are_not_used(frontend, config):
    coarser = config.model_copy(update={"verifier": config.verifier.model_copy(update={"voxel_size": 1.0})})
    assert frontend.clouds_for(config) is frontend.clouds and frontend.clouds_for(coarser) is None
    local_map = config.model_copy(update={"loop_detector": "local-map"})
    assert frontend.clouds_for(local_map) is None
    with pytest.raises(ValueError, match="frame clouds downsampled at 0.5 m .* 1.0 m voxels"):
        build_backend(
            coarser,
            frontend.descriptor,
            KeyframeCloudStore(1.0),
            PoseGraph(coarser.graph),
            len(frontend),
            "test",
            frame_clouds=frontend.clouds,
        )
