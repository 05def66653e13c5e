"""Gravity from a drive and the upright world (sim/level.py): a tilted trajectory frame is found from the
sensor's roll against its heading, a hill climbed one way does not bias it, and the world built along it is
the level drive's world seen in the tilted frame."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from msa_slam.sim.config import make_config
from msa_slam.sim.level import gravity_up, levelling_rotation, tilt_deg
from msa_slam.sim.simulation import prepare
from msa_slam.sim.world import WorldRealism, build_world

MOUNT_NOSE_DOWN_DEG = 0.7  # KITTI's Velodyne points this much below the direction of travel


def _drive(n: int = 1500, hill: bool = True, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) level-frame poses at 10 Hz, 1 m a frame round a rounded square (every heading), the sensor
    pitched down by the mounting and rolled by a random cross-fall (0.3 deg std); with `hill`, the road climbs 6 % along the
    first side only (a hill driven one way)."""
    rng = np.random.default_rng(seed)
    s = np.arange(n, dtype=float)
    yaw = 2 * np.pi * s / 400.0 + 0.3 * np.sin(s / 37.0)
    xy = np.cumsum(np.column_stack([np.cos(yaw), np.sin(yaw)]), axis=0)
    grade = np.where(hill & ((s % 400) < 100), 0.06, 0.0)
    z = np.cumsum(grade)
    roll = np.radians(0.3) * np.convolve(rng.standard_normal(n), np.ones(50) / 50**0.5, "same")
    pitch = -np.arctan(grade) + np.radians(MOUNT_NOSE_DOWN_DEG)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll])).as_matrix()
    poses[:, :3, 3] = np.column_stack([xy, z])
    return poses


def _tilted(poses: np.ndarray, rotvec_deg: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """`poses` seen in a frame turned by `rotvec_deg`, and gravity's up in that frame."""
    rot = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    out = poses.copy()
    out[:, :3, :] = np.einsum("ij,njk->nik", rot, poses[:, :3, :])
    return out, rot @ np.array([0.0, 0.0, 1.0])


def test_gravity_of_a_tilted_drive_is_found_despite_a_hill_driven_one_way():
    poses, up = _tilted(_drive(), (1.5, -1.2, 0.0))
    found = gravity_up(poses)
    assert tilt_deg(up) > 1.9
    assert np.degrees(np.arccos(np.clip(found @ up, -1, 1))) < 0.1
    flat = gravity_up(_tilted(_drive(hill=False), (1.5, -1.2, 0.0))[0])
    assert np.degrees(np.arccos(np.clip(found @ flat, -1, 1))) < 0.03  # the grade does not enter (to first order)
    assert tilt_deg(gravity_up(_drive())) < 0.1  # a level frame stays level


def test_a_drive_that_keeps_one_heading_cannot_tell_and_is_taken_as_level():
    s = np.arange(300, dtype=float)
    yaw = 0.05 * np.sin(s / 20.0)  # a street followed within 3 deg
    poses = np.tile(np.eye(4), (len(s), 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("z", yaw[:, None]).as_matrix()
    poses[:, :2, 3] = np.cumsum(np.column_stack([np.cos(yaw), np.sin(yaw)]), axis=0)
    tilted, _ = _tilted(poses, (2.0, 0.0, 0.0))
    assert np.array_equal(gravity_up(tilted), [0.0, 0.0, 1.0])


def test_levelling_rotation_takes_up_to_z_without_turning_the_headings():
    up = np.array([0.03, -0.02, 1.0]) / np.linalg.norm([0.03, -0.02, 1.0])
    rot = levelling_rotation(up)
    assert np.allclose(rot @ up, [0.0, 0.0, 1.0], atol=1e-12)
    assert np.allclose(rot @ rot.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(rot), 1.0)
    axis = Rotation.from_matrix(rot).as_rotvec()
    assert abs(axis[2]) < 1e-12  # about a horizontal axis only
    assert np.array_equal(levelling_rotation(np.array([0.0, 0.0, 1.0])), np.eye(3))
    assert np.isclose(tilt_deg(up), np.degrees(np.arccos(up[2])))


def test_an_upright_world_is_the_level_drives_world_seen_in_the_tilted_frame():
    level = _drive(300, hill=False)
    tilted, up = _tilted(level, (0.0, 2.0, 0.0))
    realism = WorldRealism(upright=True)
    world_level = build_world(level, "city", seed=3, realism=realism, up=np.array([0.0, 0.0, 1.0]))
    world_tilted = build_world(tilted, "city", seed=3, realism=realism, up=up)
    rot = levelling_rotation(up)
    dirs = np.random.default_rng(1).normal(size=(3000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origin = level[150, :3, 3]
    a = world_level.cast(origin, dirs)
    b = world_tilted.cast(rot.T @ origin, dirs @ rot)  # the same rays, in the tilted frame
    assert len(a) > 1000 and np.array_equal(a.ray, b.ray)
    assert np.allclose(a.dist, b.dist, atol=1e-6)
    assert np.allclose(b.normal, a.normal @ rot, atol=1e-9)  # normals come back in the rays' frame
    walls = np.abs(a.normal[:, 2]) < 1e-6  # vertical faces of the level world lean in the tilted frame ...
    assert walls.any() and np.allclose(np.abs(b.normal[walls] @ up), 0.0, atol=1e-9)  # ... but not against gravity
    built_along_z = build_world(tilted, "city", seed=3)  # the frame's z: walls lean by the tilt
    assert not np.allclose(built_along_z.cast(rot.T @ origin, dirs @ rot).dist[:50], b.dist[:50], atol=1e-3)


def test_kitti_preset_builds_kitti_09_upright_and_clean_does_not():
    kitti = prepare(make_config(trajectory="kitti-09", end=3, azimuth_steps=90))
    clean = prepare(make_config(trajectory="kitti-09", end=3, azimuth_steps=90, realism="clean"))
    assert clean.world.levelling is None
    up = np.linalg.inv(kitti.world.levelling) @ np.array([0.0, 0.0, 1.0])
    assert 1.5 < tilt_deg(up) < 3.0  # KITTI-09 starts on a climb: its first frame leans back against gravity
    assert up @ kitti.poses[0, :3, 0] > 0  # gravity's up leans towards the first frame's forward axis
