"""First hits of rays on a triangle mesh with Embree (embreex), as trimesh's
`RayMeshIntersector.intersects_id(..., multiple_hits=False)` finds them: the same scaling of the mesh and the rays
into Embree's float32 and the same unit directions, so the same triangles. Kept by hand (a few lines over embreex)
because trimesh's general query copies every ray array three to four times and checks its scene cache on each call:
about 5 ms of a live scan's 40 ms of simulation (docs/performance.md), on the path of every simulated frame."""

from __future__ import annotations

import numpy as np
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh
from trimesh.util import unitize

BOX_SIZE = 100.0  # the mesh is scaled to about this size (trimesh's scale_to_box), for Embree's float32 precision


class FirstHits:
    """An Embree scene of `mesh`; `cast(origins, directions)` gives (hit triangle, ray index) of each ray that hits."""

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        self.mesh = mesh
        vertices = np.array(mesh.vertices, dtype=np.float64)
        self.origin = vertices.min(axis=0)
        self.scale = float(BOX_SIZE / mesh.scale)
        self.scene = rtcore_scene.EmbreeScene()
        TriangleMesh(
            scene=self.scene,
            vertices=((vertices - self.origin) * self.scale).astype(np.float32),
            indices=np.asarray(mesh.faces).astype(np.int32),
        )

    def __reduce__(self) -> tuple[type[FirstHits], tuple[trimesh.Trimesh]]:
        """Pickled as its mesh (a world sent to another process): Embree's scene is rebuilt there."""
        return FirstHits, (self.mesh,)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(triangles (k,) int64, rays (k,) int64, ascending) first hit by the rays from `origins` ((R, 3), or a
        broadcast view of one origin) along `directions` (R, 3; unitised here)."""
        if np.shape(origins) != np.shape(directions):
            raise ValueError(f"ray origins {np.shape(origins)} and directions {np.shape(directions)} differ in shape")
        unit = unitize(np.ascontiguousarray(directions, dtype=np.float64))
        scaled = (np.asarray(origins, dtype=np.float64) - self.origin) * self.scale
        query = self.scene.run(scaled.astype(np.float32), unit.astype(np.float32))
        rays = np.flatnonzero(query != -1)
        return query[rays].astype(np.int64), rays
