"""The SLAM core on its own: frames in, keyframes, loops and a result out; what it refuses."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.slam import config_backend

from msa_slam.backend import PoseGraph
from msa_slam.descriptors import ScanContext
from msa_slam.errors import InputError
from msa_slam.pipeline import make_config
from msa_slam.registration import KeyframeCloudStore
from msa_slam.sampling import make_sampler


class _Replaying:
    """A sampler answering each push with a scripted list of keyframes (to reach the core's checks)."""

    needs_points = False

    def __init__(self, script: dict[int, list[int]], window: tuple[int, ...] = ()) -> None:
        self.script, self.window, self.frame = script, window, 0

    def expect_frames(self, n: int, flush: bool = False) -> None:
        pass

    def push(self, pose, descriptor, points=None) -> list[int]:
        self.frame += 1
        return self.script.get(self.frame - 1, [])


def _frames(n: int):
    rng = np.random.default_rng(0)
    for i in range(n):
        pose = np.eye(4)
        pose[0, 3] = 2.0 * i
        yield pose, rng.uniform(-20, 20, (2000, 3))


def _backend(n: int, sampler="all"):
    config = make_config(dataset="x", sampler=sampler if isinstance(sampler, str) else "all")
    return config_backend(
        config,
        ScanContext(),
        KeyframeCloudStore(0.5),
        PoseGraph(),
        n,
        "stub",
        None if isinstance(sampler, str) else sampler,
    )


def test_core_streams_frames_into_keyframes_and_a_result():
    backend = _backend(6)
    descriptor = ScanContext()
    for i, (pose, points) in enumerate(_frames(6)):
        assert backend.add_frame(pose, descriptor.compute(points), points, pose, 0.5 * i) == [i]
    result = backend.finish()
    assert result.keyframes.tolist() == list(range(6)) and len(result.optimised) == 6
    np.testing.assert_array_equal(result.times, 0.5 * np.arange(6))
    assert result.memory_bytes["cloud_bytes"] > 0 and result.memory_bytes["descriptor_bytes"] > 0


@pytest.mark.parametrize(
    "window, error",
    [
        ((), "chose frame 0 at frame 2, but frame 0 had left its window"),
        ((0, 1, 2), "chose frame 0 after keyframe 1 .keyframes must come in time order"),
    ],
)
def test_keyframes_the_sampler_can_no_longer_give_are_refused(window, error):
    backend = _backend(4, _Replaying({1: [1], 2: [0]}, window))
    descriptor = ScanContext()
    frames = list(_frames(4))
    backend.add_frame(frames[0][0], descriptor.compute(frames[0][1]), frames[0][1], frames[0][0], 0.0)
    backend.add_frame(frames[1][0], descriptor.compute(frames[1][1]), frames[1][1], frames[1][0], 0.1)
    with pytest.raises(RuntimeError, match=error):
        backend.add_frame(frames[2][0], descriptor.compute(frames[2][1]), frames[2][1], frames[2][0], 0.2)


def test_ground_truth_for_all_frames_or_none_and_oracle_needs_it():
    pose, points = next(_frames(1))
    descriptor = ScanContext().compute(points)
    with pytest.raises(InputError, match="no ground-truth poses, which the oracle mode needs"):
        _backend(3).add_frame(pose, descriptor, points, None, 0.0)
    backend = _backend(3)
    backend.add_frame(pose, descriptor, points, pose, 0.0)
    with pytest.raises(InputError, match="frame 1 lacks a ground-truth pose but frame 0 has one"):
        backend.add_frame(pose, descriptor, points, None, 0.1)


def test_lazy_scans_are_read_only_for_keyframes():
    reads = []
    backend = _backend(6, "constant")
    backend.sampler = make_sampler("constant", distance=4.0)
    descriptor = ScanContext()
    for i, (pose, points) in enumerate(_frames(6)):
        backend.add_frame(pose, descriptor.compute(points), lambda i=i, p=points: reads.append(i) or p, pose, i)
    result = backend.finish()
    assert reads == result.keyframes.tolist() and len(reads) < 6
