"""The simulator's own Embree query finds the triangles trimesh's general query finds, on a street of the simulator."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

from msa_slam.sim.raycast import FirstHits


def _rays(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    origins = rng.uniform(-3.0, 3.0, (n, 3))
    directions = rng.normal(size=(n, 3))
    return origins, directions / np.linalg.norm(directions, axis=1, keepdims=True)


def test_first_hits_are_trimesh_s_on_a_mesh_with_misses():
    mesh = trimesh.util.concatenate([trimesh.creation.box((4.0, 4.0, 4.0)), trimesh.creation.icosphere(2, 1.0)])
    origins, directions = _rays(5000, 0)
    directions[::7] = [0.0, 0.0, 1.0]
    origins[::7] = [10.0, 10.0, 10.0]  # pointing away from everything: misses
    tri, ray = FirstHits(mesh).cast(origins, directions)
    expected_tri, expected_ray = RayMeshIntersector(mesh).intersects_id(origins, directions, multiple_hits=False)
    assert 0 < len(ray) < len(origins)
    assert np.array_equal(ray, expected_ray) and np.array_equal(tri, expected_tri)
    assert tri.dtype == expected_tri.dtype and ray.dtype == expected_ray.dtype


def test_one_origin_broadcast_gives_the_hits_of_its_copies():
    mesh = trimesh.creation.icosphere(3, 5.0)
    _, directions = _rays(2000, 1)
    one = np.broadcast_to(np.array([0.5, -0.2, 0.1]), directions.shape)
    hits = FirstHits(mesh).cast(one, directions)
    assert len(hits[1]) == len(directions)  # every ray from inside a closed sphere hits it
    assert all(np.array_equal(a, b) for a, b in zip(hits, FirstHits(mesh).cast(one.copy(), directions)))


def test_a_pickled_scene_finds_the_same_hits():
    mesh = trimesh.creation.box((2.0, 3.0, 4.0))
    origins, directions = _rays(1000, 2)
    first = FirstHits(mesh)
    again = pickle.loads(pickle.dumps(first))
    assert all(np.array_equal(a, b) for a, b in zip(first.cast(origins, directions), again.cast(origins, directions)))


def test_mismatched_rays_are_refused():
    with pytest.raises(ValueError, match="differ in shape"):
        FirstHits(trimesh.creation.box()).cast(np.zeros((3, 3)), np.ones((4, 3)))
