"""The standstill gate: frames that do not move beyond odometry jitter are no keyframe candidates.

Rule (sampling/base.py): a frame whose translation from the last frame passed on to the sampler is below
`min_motion` metres and whose rotation from it is below `min_rotation` degrees is held back. make_sampler's
default is off (the reference's behaviour, which the parity tests check); the SLAM core switches it on
(slam/build.py, STANDSTILL_GATE: 0.1 m, 0.5 deg) for every sampler but "all".

The jitter below is that of KISS-ICP on simulated KITTI-like scans from one fixed pose (docs/msa.md, "Standing
still"): steps of about 1.2 cm (median), at most 5.2 cm and 0.115 deg from the first pose over 1,000 frames.
Bound: over a 1,000-frame standstill that starts at a passed frame, the gated samplers make no keyframe (only
frame 0 when the stream starts standing), and neither the sampler's nor the SLAM core's accounted bytes grow
apart from the run's per-frame trajectory record (its pose, ground truth, time and step times).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import SHARED_DIR
from helpers.slam import config_backend
from scipy.spatial.transform import Rotation

from msa_slam.backend import PoseGraph
from msa_slam.descriptors import make_descriptor
from msa_slam.errors import InputError
from msa_slam.experiments.compare import method_configs
from msa_slam.pipeline.config import apply_params, make_config
from msa_slam.registration import KeyframeCloudStore
from msa_slam.sampling import make_sampler, sampler_parameters
from msa_slam.sampling.registry import SAMPLERS
from msa_slam.slam.build import STANDSTILL_GATE, slam_sampler_params

STANDSTILL = 1000
REPORTED = 200  # frames of the reported standstill (41 keyframes without the gate)
JITTER_M, JITTER_MAX_M = 0.01, 0.045  # per axis (sigma) and largest offset: two frames stay < 0.1 m apart
JITTER_DEG, JITTER_MAX_DEG = 0.03, 0.1
GATE = dict(STANDSTILL_GATE)
PARITY = SHARED_DIR / "parity" / "stream_s1_vec256.npz"


def _jittered(pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """`pose` moved by odometry-like jitter (bounded as measured)."""
    offset = rng.normal(0.0, JITTER_M, 3)
    offset *= min(1.0, JITTER_MAX_M / np.linalg.norm(offset))
    angle = min(abs(rng.normal(0.0, JITTER_DEG)), JITTER_MAX_DEG)
    axis = rng.normal(size=3)
    out = pose.copy()
    out[:3, :3] = Rotation.from_rotvec(np.radians(angle) * axis / np.linalg.norm(axis)).as_matrix() @ pose[:3, :3]
    out[:3, 3] += offset
    return out


def _drive(n: int, start: np.ndarray, step: float = 1.0, turn_deg: float = 2.0) -> np.ndarray:
    """A curving drive of `n` frames after `start`, `step` metres apart."""
    move = np.eye(4)
    move[:3, :3] = Rotation.from_euler("z", turn_deg, degrees=True).as_matrix()
    move[0, 3] = step
    poses = [start]
    for _ in range(n):
        poses.append(poses[-1] @ move)
    return np.stack(poses[1:])


def _descriptors(n: int, rng: np.random.Generator, shape=(20, 60)) -> np.ndarray:
    """Scan-Context-like descriptors: one place's, each with noise (jittered descriptors)."""
    base = rng.uniform(0.0, 3.0, shape)
    return np.clip(base + rng.normal(0.0, 0.05, (n, *shape)), 0.0, None)


def _standstill_stream(seed: int = 0):
    rng = np.random.default_rng(seed)
    poses = np.stack([_jittered(np.eye(4), rng) for _ in range(STANDSTILL)])
    poses[0] = np.eye(4)
    return poses, _descriptors(STANDSTILL, rng)


def _drive_stop_drive(seed: int = 1, drive: int = 60):
    """`drive` moving frames, STANDSTILL jittered frames at the last one's pose, `drive` moving frames on."""
    rng = np.random.default_rng(seed)
    first = _drive(drive, np.eye(4))
    stop = np.stack([_jittered(first[-1], rng) for _ in range(STANDSTILL)])
    second = _drive(drive, first[-1])
    poses = np.concatenate([first, stop, second])
    return poses, _descriptors(len(poses), rng), slice(drive, drive + STANDSTILL)


def test_a_1000_frame_standstill_makes_no_keyframe_with_the_gate():
    """Without the gate MSA makes a keyframe every few frames of jitter (the reported 41 of 200); with it frame 0
    stays the only one, flushed or not, and the sampler's accounted bytes do not grow."""
    poses, descriptors = _standstill_stream()
    ungated = make_sampler("msa", window=10)
    ungated.run(poses[:REPORTED], descriptors[:REPORTED])  # the reported stream's length shows it: 1/5 of the cost
    assert len(ungated.online_keyframes) > REPORTED // 20  # the problem the gate solves
    gated = make_sampler("msa", window=10, **GATE)
    sizes = []
    with pytest.warns(
        UserWarning,
        match=r"never filled in 1000 frames \(only 1 moved at least 0\.01 m from the "
        r"member before them; the standstill gate held back 999 that moved < 0\.1 m\)",
    ):
        for pose, descriptor in zip(poses, descriptors):
            gated.push(pose, descriptor)
            sizes.append(gated.nbytes)
        gated.finish()
    assert gated.keyframes == [0]
    assert gated.stats.standstill_frames == STANDSTILL - 1 and gated.stats.frames == STANDSTILL
    assert max(sizes[1:]) == min(sizes[1:])  # bounded: nothing the sampler keeps grows with the frames
    assert ungated.nbytes > gated.nbytes


@pytest.mark.parametrize(
    "name, params",
    [
        ("msa", {"window": 10}),
        ("msa", {"window": 8, "mode": "fast"}),
        ("constant", {"distance": 0.02}),
        ("entropy", {}),
        ("spaciousness", {}),
    ],
)
def test_a_stop_between_drives_is_as_if_it_had_not_happened(name, params):
    """Drive, stand 1,000 frames, drive on: the gated sampler's keyframes are those of the sampler run on the
    drives alone (standstill frames removed, indices mapped back), and its accounted bytes are the same at the
    start and at the end of the stop."""
    poses, descriptors, stop = _drive_stop_drive()
    rng = np.random.default_rng(5)
    clouds = [rng.uniform(-20, 20, (300, 3)) * (1 + 0.01 * rng.standard_normal()) for _ in range(len(poses))]
    gated = make_sampler(name, **params, **GATE)
    sizes = {}
    for i in range(len(poses)):
        gated.push(poses[i], descriptors[i], clouds[i])
        if i in (stop.start, stop.stop - 1):
            sizes[i] = gated.nbytes
    gated.finish()
    moving = np.r_[0 : stop.start, stop.stop : len(poses)]
    alone = make_sampler(name, **params).run(
        poses[moving], descriptors[moving], [clouds[i] for i in moving], flush=True
    )
    assert gated.keyframes == [int(moving[k]) for k in alone]
    assert not set(gated.keyframes) & set(range(stop.start, stop.stop))
    assert gated.stats.standstill_frames == STANDSTILL
    assert sizes[stop.start] == sizes[stop.stop - 1]


@pytest.mark.parametrize(
    "name, params",
    [("msa", {"window": 10}), ("constant", {"distance": 2.0}), ("entropy", {}), ("spaciousness", {}), ("all", {})],
)
def test_moving_streams_keep_their_keyframes(name, params):
    """Every frame moves 0.2-1 m: the gate holds back nothing and the keyframes are those without it."""
    rng = np.random.default_rng(3)
    steps = rng.uniform(0.2, 1.0, 240)
    poses = np.concatenate([_drive(1, np.eye(4), 0.0)] + [_drive(1, np.eye(4), s) for s in steps])
    poses[:, :3, 3] = np.cumsum(poses[:, :3, 3], axis=0)
    descriptors = _descriptors(len(poses), rng, (256,))
    clouds = [rng.uniform(-30, 30, (300, 3)) for _ in range(len(poses))]
    without = make_sampler(name, **params)
    gated = make_sampler(name, **params, **GATE)
    assert gated.run(poses, descriptors, clouds, flush=True) == without.run(poses, descriptors, clouds, flush=True)
    assert gated.stats.standstill_frames == 0


@pytest.mark.skipif(not PARITY.exists(), reason="needs ../shared/parity (the reference's keyframes)")
def test_the_gate_is_off_in_the_samplers_own_defaults_so_parity_is_unchanged():
    """make_sampler's defaults (the parity tests' API) hold back nothing and reproduce the reference. The SLAM
    core's gate would hold back frame 157 of this parity stream (0.6 mm and 0.13 deg after frame 156): the
    reference processes every frame, which is why the gate is not the samplers' default."""
    data = np.load(PARITY)
    poses, descriptors = data["poses"], data["descriptors"]
    expected = json.loads(str(data["expected"]))["msa_N10_nn0_a1_b1_l0.1_u3"]
    default = make_sampler("msa", window=10, lambda_u=3.0)
    assert default.min_motion == default.min_rotation == 0.0
    assert default.run(poses, descriptors) == expected and default.stats.standstill_frames == 0
    gated = make_sampler("msa", window=10, lambda_u=3.0, **GATE)
    gated.run(poses, descriptors)
    assert gated.stats.standstill_frames >= 1


def test_compare_gives_the_gate_given_to_every_method_but_all():
    """-p min_motion=... reaches the baselines too (the same frames for every method); other MSA parameters
    stay with MSA."""
    base = apply_params(make_config(dataset="sim:test"), ["window=8", "min_motion=0.2", "min_rotation=1"])
    configs = {c.name: c.sampler_params for c in method_configs(base)}
    assert configs["msa"] == {"window": 8, "min_motion": 0.2, "min_rotation": 1}
    assert configs["constant-2m"] == {"min_motion": 0.2, "min_rotation": 1, "distance": 2.0}
    assert configs["entropy"] == configs["spaciousness"] == {"min_motion": 0.2, "min_rotation": 1}
    assert configs["all"] == {}
    assert {c.name: c.sampler_params for c in method_configs(make_config(dataset="sim:test"))}["entropy"] == {}


def test_the_slam_core_gates_every_sampler_but_all():
    for name in SAMPLERS:
        params = slam_sampler_params(name, {})
        assert params == ({} if name == "all" else GATE)
    assert slam_sampler_params("msa", {"min_motion": 0}) == {"min_motion": 0, "min_rotation": 0.0}  # gate off
    assert slam_sampler_params("msa", {"min_motion": 0.2}) == {"min_motion": 0.2, "min_rotation": 0.5}
    assert slam_sampler_params("constant", {"min_rotation": 2}) == {"min_motion": 0.1, "min_rotation": 2}
    make_sampler("msa", **slam_sampler_params("msa", {"min_motion": 0}))  # no "min_rotation needs min_motion"
    assert all({"min_motion", "min_rotation"} <= set(sampler_parameters(name)) for name in SAMPLERS)


@pytest.mark.parametrize(
    "params, message",
    [
        ({"min_motion": -0.1}, r"min_motion=-0\.1 is not allowed; expected a finite number >= 0"),
        ({"min_motion": float("nan")}, r"min_motion=nan is not allowed"),
        ({"min_motion": "0.1"}, r"min_motion='0\.1' is not allowed"),
        ({"min_motion": True}, r"min_motion=True is not allowed"),
        (
            {"min_motion": 0.1, "min_rotation": 180},
            r"min_rotation=180 is not allowed; expected a finite number >= 0 "
            r"and < 180",
        ),
        ({"min_motion": 0.1, "min_rotation": -1}, r"min_rotation=-1 is not allowed"),
        ({"min_rotation": 0.5}, r"min_rotation=0\.5 needs min_motion > 0"),
        ({"min_motoin": 0.1}, r"unknown parameter\(s\) min_motoin; it takes: .*min_motion=0\.0, min_rotation=0\.0"),
    ],
)
@pytest.mark.parametrize("name", ["msa", "constant", "all"])
def test_bad_gate_values_are_refused_naming_them(name, params, message):
    with pytest.raises(InputError, match=f"sampler '{name}': " + message):
        make_sampler(name, **params)


def _backend(sampler: str, frames: int, **params):
    config = make_config(dataset="unused", sampler=sampler, sampler_params=params, mode="realistic")
    descriptor = make_descriptor("sc")
    return config_backend(
        config,
        descriptor,
        KeyframeCloudStore(config.verifier.voxel_size),
        PoseGraph(config.graph, mode=config.mode),
        frames,
        "standstill",
    )


def test_the_slam_cores_accounted_memory_does_not_grow_while_standing_still():
    """Drive, stand 1,000 frames, drive on through the SLAM core with its default gate: keyframe clouds,
    descriptors, graph and pending scans are the same before and after the stop; the run's records grow by
    the per-frame trajectory record only (the stop's poses stay in the trajectory and its evaluation)."""
    poses, descriptors, stop = _drive_stop_drive(drive=30)
    rng = np.random.default_rng(2)
    world = rng.uniform(-25, 25, (1500, 3))
    backend = _backend("msa", len(poses), window=6)
    memory = {}
    for i, pose in enumerate(poses):
        cloud = (world - pose[:3, 3]) @ pose[:3, :3]
        backend.add_frame(pose, descriptors[i].astype(np.float32), cloud, pose, 0.1 * i)
        if i in (stop.start, stop.stop - 1):
            memory[i] = {**backend.memory_bytes(), "pending": backend.pending_bytes, "sampler": backend.sampler.nbytes}
    before, after = memory[stop.start], memory[stop.stop - 1]
    per_frame = (
        backend.odometry[0].nbytes
        + backend.gt[0].nbytes
        + backend.times.itemsize
        + sum(v.itemsize for v in backend.steps_ms.values())
    )  # 284 bytes: pose, ground truth, times
    assert after.pop("record_bytes") - before.pop("record_bytes") == (STANDSTILL - 1) * per_frame
    assert after == before
    result = backend.finish()
    assert not set(result.keyframes.tolist()) & set(range(stop.start, stop.stop))
    assert len(result.odometry) == len(poses)  # every frame's pose is in the trajectory
    assert result.sampler_stats["standstill_frames"] == STANDSTILL
    backend.close()
