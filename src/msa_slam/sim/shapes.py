"""Vectorised mesh primitives (boxes, prisms, blobs, height-field patches) as raw vertex/face arrays.

The world holds tens of thousands of primitives; building them in batches of numpy arrays and
concatenating once is orders of magnitude faster than one trimesh object per primitive.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
import trimesh


class Material(IntEnum):
    """What a surface is, per face and per hit: the sensor treats vegetation and moving things apart."""

    SOLID = 0  # buildings, walls, poles, trunks, barriers
    GROUND = 1
    VEGETATION = 2  # tree crowns, hedges: porous, their returns vary from scan to scan
    VEHICLE = 3  # parked or moving cars
    PERSON = 4


_BOX_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
# Outward-facing triangles of the unit cube whose corners are ordered as above (x major, z minor).
_BOX_FACES = np.array(
    [
        [0, 1, 3],
        [0, 3, 2],
        [4, 6, 7],
        [4, 7, 5],  # -x, +x
        [0, 4, 5],
        [0, 5, 1],
        [2, 3, 7],
        [2, 7, 6],  # -y, +y
        [0, 2, 6],
        [0, 6, 4],
        [1, 5, 7],
        [1, 7, 3],  # -z, +z
    ]
)


def _yaw_matrices(yaw: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.zeros((len(yaw), 3, 3))
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = c, -s, s, c, 1.0
    return rot


@dataclass
class MeshBuilder:
    """Accumulates primitive batches with a reflectance and a `Material` per primitive; `build()` gives
    one mesh."""

    vertices: list[np.ndarray] = field(default_factory=list)
    faces: list[np.ndarray] = field(default_factory=list)
    reflectance: list[np.ndarray] = field(default_factory=list)
    material: list[np.ndarray] = field(default_factory=list)
    _count: int = 0

    def _add(
        self, verts: np.ndarray, faces: np.ndarray, refl: np.ndarray, material: np.ndarray | int = Material.SOLID
    ) -> None:
        self.vertices.append(verts.reshape(-1, 3))
        self.faces.append(faces.reshape(-1, 3) + self._count)
        self.reflectance.append(refl)
        self.material.append(np.broadcast_to(np.asarray(material, dtype=np.uint8), refl.shape).copy())
        self._count += len(self.vertices[-1])

    def boxes(
        self,
        centers: np.ndarray,
        half: np.ndarray,
        yaw: np.ndarray,
        refl: np.ndarray,
        material: np.ndarray | int = Material.SOLID,
    ) -> None:
        """Boxes (K,) given centres (K, 3), half extents (K, 3), yaw about z (K,), reflectance (K,) and
        material (scalar or (K,))."""
        k = len(centers)
        if k == 0:
            return
        local = _BOX_CORNERS[None] * half[:, None, :]
        verts = np.einsum("kij,kvj->kvi", _yaw_matrices(yaw), local) + centers[:, None, :]
        faces = _BOX_FACES[None] + 8 * np.arange(k)[:, None, None]
        self._add(verts, faces, np.repeat(refl, 12), np.repeat(material, 12) if np.ndim(material) else material)

    def prisms(
        self, bases: np.ndarray, radius: np.ndarray, height: np.ndarray, refl: np.ndarray, sides: int = 8
    ) -> None:
        """Vertical `sides`-gon prisms (poles, trunks) standing on `bases` (K, 3)."""
        k = len(bases)
        if k == 0:
            return
        ang = np.linspace(0, 2 * np.pi, sides, endpoint=False)
        ring = np.column_stack([np.cos(ang), np.sin(ang)])
        verts = np.zeros((k, 2 * sides, 3))
        verts[:, :sides, :2] = ring[None] * radius[:, None, None]
        verts[:, sides:, :2] = verts[:, :sides, :2]
        verts[:, sides:, 2] = height[:, None]
        verts += bases[:, None, :]
        i = np.arange(sides)
        j = (i + 1) % sides
        side = np.concatenate([np.column_stack([i, j, j + sides]), np.column_stack([i, j + sides, i + sides])])
        top = np.column_stack(
            [np.full(sides - 2, sides), np.arange(sides + 1, 2 * sides - 1), np.arange(sides + 2, 2 * sides)]
        )
        tmpl = np.concatenate([side, top])
        faces = tmpl[None] + 2 * sides * np.arange(k)[:, None, None]
        self._add(verts, faces, np.repeat(refl, len(tmpl)))

    def blobs(self, centers: np.ndarray, radii: np.ndarray, refl: np.ndarray, rng: np.random.Generator) -> None:
        """Irregular ellipsoidal blobs (tree crowns, bushes): jittered icospheres, radii (K, 3)."""
        k = len(centers)
        if k == 0:
            return
        sphere = trimesh.creation.icosphere(subdivisions=1)
        jitter = 1.0 + 0.18 * rng.standard_normal((k, len(sphere.vertices), 1))
        verts = sphere.vertices[None] * jitter * radii[:, None, :] + centers[:, None, :]
        faces = sphere.faces[None] + len(sphere.vertices) * np.arange(k)[:, None, None]
        self._add(verts, faces, np.repeat(refl, len(sphere.faces)), Material.VEGETATION)

    def height_field(self, origin: np.ndarray, cell: float, heights: np.ndarray, keep: np.ndarray, refl: float) -> None:
        """Ground: a grid of `heights` (ny+1, nx+1) from `origin` (x0, y0); only cells where `keep` (ny, nx)."""
        ny, nx = keep.shape
        gy, gx = np.mgrid[0 : ny + 1, 0 : nx + 1]
        verts = np.column_stack([origin[0] + gx.ravel() * cell, origin[1] + gy.ravel() * cell, heights.ravel()])
        cy, cx = np.nonzero(keep)
        v00 = cy * (nx + 1) + cx
        v10, v01, v11 = v00 + 1, v00 + nx + 1, v00 + nx + 2
        faces = np.concatenate([np.column_stack([v00, v10, v11]), np.column_stack([v00, v11, v01])])
        self._add(verts, faces, np.full(len(faces), refl), Material.GROUND)

    def build(self) -> tuple[trimesh.Trimesh, np.ndarray, np.ndarray]:
        """One mesh (no vertex merging, so faces keep their order), its per-face reflectance (float32) and
        per-face `Material` codes (uint8)."""
        mesh = trimesh.Trimesh(np.concatenate(self.vertices), np.concatenate(self.faces), process=False)
        return mesh, np.concatenate(self.reflectance).astype(np.float32), np.concatenate(self.material)
