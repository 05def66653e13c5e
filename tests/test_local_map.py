"""The local map around a keyframe (slam/local_map.py): merged in the keyframe's sensor frame, causal (frames after
the keyframe never enter its map), bounded (frames beyond local_map_m of path behind the oldest frame that may
still become a keyframe are forgotten) and accounted; and the settings that choose loop detection and protocol."""

from __future__ import annotations

import numpy as np
import pytest

from msa_slam.errors import InputError
from msa_slam.pipeline.config import make_config
from msa_slam.slam.local_map import LocalMap
from msa_slam.slam.loop_closing import acceptance, protocol


def _pose(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    pose = np.eye(4)
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[0, 3] = x
    return pose


def _wall(x: float) -> np.ndarray:
    """A 2 m x 2 m patch of points at world x = `x`, as seen from a sensor at the origin."""
    g = np.linspace(-1, 1, 21)
    yy, zz = np.meshgrid(g, g)
    return np.column_stack([np.full(yy.size, x), yy.ravel(), zz.ravel()])


def test_the_map_is_in_the_keyframe_sensor_frame_and_causal():
    lm = LocalMap(length_m=60.0, voxel_size=0.5)
    lm.add(0, _pose(0.0), _wall(5.0))  # a wall at world x = 5
    lm.add(1, _pose(2.0, 90.0), _wall(50.0))  # turned left; its wall is at world y = 50
    lm.add(2, _pose(4.0), _wall(40.0))  # after frame 1: never in its map
    cloud = lm.around(1)
    # frame 0's wall seen from frame 1 (at x = 2, facing +y): 3 m ahead in x is 3 m to its right (-y)
    assert np.allclose(np.median(cloud[cloud[:, 0] < 10], axis=0), [0.0, -3.0, 0.0], atol=0.3)
    assert cloud[:, 0].max() == pytest.approx(50.0, abs=0.5)  # its own wall, 50 m ahead
    assert np.abs(cloud).max() < 60  # nothing of frame 2
    assert cloud.dtype == np.float32


def test_frames_beyond_the_length_are_left_out_and_forgotten():
    lm = LocalMap(length_m=10.0, voxel_size=0.5)
    for i in range(30):
        lm.add(i, _pose(float(i)), _wall(2.0))  # frame i's wall at world x = i + 2
    assert len(lm.around(29)) == len(lm.around(12))  # both hold 11 frames' walls (10 m of path)
    frames = np.unique(np.round(lm.around(29)[:, 0] + 29)) - 2
    assert frames.min() == 19 and frames.max() == 29
    far = LocalMap(length_m=10.0, voxel_size=0.5)
    far.add(0, _pose(0.0), np.vstack([_wall(9.0), _wall(11.0)]))
    assert far.around(0)[:, 0].max() < 10  # cropped to length_m around the keyframe
    before = lm.nbytes
    lm.forget_before(25)  # the oldest frame that may still become a keyframe
    assert len(lm) == 30 - 15 and lm.nbytes < before
    lm.around(25)
    with pytest.raises(InputError, match="frame 5 is not held"):
        lm.around(5)
    with pytest.raises(InputError, match="frames must come in order"):
        lm.add(3, _pose(0.0), _wall(1.0))


@pytest.mark.parametrize(
    "override, message",
    [
        ({"loop_detector": "mapclosures"}, "loop_detector"),
        ({"loop_protocol": "strict"}, "loop_protocol"),
        ({"verified_top_k": 0}, "verified_top_k"),
        ({"local_map_m": -5.0}, "local_map_m"),
        ({"verified_min_similarity": 1.5}, "verified_min_similarity"),
    ],
)
def test_bad_loop_settings_are_one_clear_error(override, message):
    with pytest.raises(InputError, match=message):
        make_config(dataset="unused", **override)


def test_auto_protocol_follows_the_mode():
    oracle, realistic = (make_config(dataset="x", mode=mode, loop_protocol="auto") for mode in ("oracle", "realistic"))
    assert (protocol(oracle), acceptance(oracle)) == ("paper", (0.8, 1))
    assert (protocol(realistic), acceptance(realistic)) == ("verified", (0.3, 3))
    default = make_config(dataset="x", mode="realistic")
    assert (default.loop_protocol, protocol(default)) == ("auto", "verified")
    forced = make_config(dataset="x", mode="realistic", loop_protocol="paper", top_k=2)
    assert acceptance(forced) == (0.8, 2)
