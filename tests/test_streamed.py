"""`run`'s back end beside its odometry (pipeline.streamed): a cold run streams each frame to the back end as its
pose is computed and gets the result of the front end computed first, to the bit; a warm run replays the cache
instead; a back end that fails mid-stream stops the pass, which leaves no process and no odometry entry behind."""

from __future__ import annotations

import multiprocessing

import numpy as np
import pytest
from helpers.metrics import metrics_json
from helpers.results import differences, stable_content

from msa_slam.errors import InputError
from msa_slam.odometry import sequence_odometry
from msa_slam.odometry.choice import make_odometry
from msa_slam.pipeline import make_config, prepare_frontend, run
from msa_slam.pipeline.frontend import CachedFrontEnd
from msa_slam.pipeline.streamed import StreamedFrontEnd, open_frontend
from msa_slam.reporting.results import write_run_files
from msa_slam.slam import SlamBackend

# KISS-ICP with coarse voxels on the simulated figure-eight: seconds of odometry, loops at the crossing
ODOMETRY = {"voxel_size": 1.5}


def _config(sequence, cache, **changes):
    return make_config(
        dataset=str(sequence), cache_dir=str(cache), mode="realistic", odometry_params=ODOMETRY, **changes
    )


def test_a_cold_run_streams_and_writes_what_the_computed_front_end_gives(sequence, tmp_path):
    config = _config(sequence, tmp_path / "cache")
    front = open_frontend(config)
    assert isinstance(front, StreamedFrontEnd)
    streamed = _written(lambda: run(config, front), tmp_path / "streamed")
    assert not multiprocessing.active_children()
    assert isinstance(open_frontend(config), CachedFrontEnd)  # the pass cached its stages: a re-run replays them
    computed = _written(lambda: run(config, prepare_frontend(config)), tmp_path / "computed")
    assert len(streamed.keyframes) > 3 and sum(loop.accepted for loop in streamed.loops) > 0
    for name in ("odometry", "keyframes", "optimised", "descriptors", "map_points"):  # at full precision
        np.testing.assert_array_equal(getattr(streamed, name), getattr(computed, name), err_msg=name)
    assert not differences(stable_content(tmp_path / "streamed"), stable_content(tmp_path / "computed"))
    # the odometry the forked pass computed is KISS-ICP's in this process, to the bit
    in_process = sequence_odometry(
        front.plan.sequence, make_odometry(config, len(streamed.odometry), front.plan.sequence.point_times), quiet=True
    )
    np.testing.assert_array_equal(streamed.odometry, in_process.values)
    assert metrics_json(streamed)["frontend_cached"] == {"odometry": False, "descriptors": False, "clouds": False}
    assert metrics_json(computed)["frontend_cached"] == {"odometry": True, "descriptors": True, "clouds": True}


def _written(make, out):
    """The result of `make()`, its files written to `out` as `run` writes them (figures left out)."""
    result = make()
    out.mkdir()
    write_run_files(result, out, figures=False)
    return result


def test_a_back_end_failing_mid_stream_stops_the_pass(sequence, tmp_path, monkeypatch):
    config = _config(sequence, tmp_path / "cache")
    add_frame = SlamBackend.add_frame

    def failing(self, *args, **kwargs):
        if self._frames == 20:
            raise InputError("frame 20: refused by the test")
        return add_frame(self, *args, **kwargs)

    monkeypatch.setattr(SlamBackend, "add_frame", failing)
    with pytest.raises(InputError, match="frame 20"):
        run(config)
    assert not multiprocessing.active_children()
    assert isinstance(open_frontend(config), StreamedFrontEnd)  # nothing half-written: the odometry is not cached


def test_a_streamed_front_end_runs_only_its_own_config(sequence, tmp_path):
    config = _config(sequence, tmp_path / "cache")
    front = open_frontend(config)
    assert isinstance(front, StreamedFrontEnd)
    with pytest.raises(InputError, match="only the configuration it was opened for"):
        front.start(config.model_copy(update={"sampler": "all"}))
    front.close()
    assert not multiprocessing.active_children()
