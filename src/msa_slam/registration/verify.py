"""Loop-closure verification by GICP registration (small_gicp; Koide, ICRA 2024) with a metric residual gate.

The paper (its section V-A) accepts a loop when the registration residual is below 0.3 m. Here the
residual is the RMS point-to-plane distance, after alignment, of the source points whose nearest target
point lies within `max_correspondence_distance` (the inliers); point-to-plane rather than point-to-point
so the value does not grow with the voxel spacing of the downsampled clouds. A loop also needs enough
inliers and overlap on BOTH clouds (the fraction of each cloud's points with a point of the other within
`max_correspondence_distance`), so a small cloud that fits inside a large one, or a cloud that touches the
target in a few places, cannot pass. A `strict` verification (loops found with no odometry prior: the verified
loop protocol) also needs the structure to fit: the median point-to-plane distance of the source's inlier points
on non-horizontal surfaces (walls, poles, trunks: a normal less than ~45 deg from horizontal) at most
`max_structure_residual`. A street built from the same design elsewhere aligns its ground and its rough shape, so
overlap and RMS residual hardly tell it apart (simulated KITTI-05 local maps: RMS 0.27 m for the look-alike, 0.26 m
for a true revisit driven the other way round), but its walls sit a little off: structure median 0.21-0.24 m
against 0.08 m for the true revisit (0.28-0.31 m for unrelated places). Failing it counts as `residual`. The estimate's covariance comes from the GICP Hessian at the solution
(registration_covariance) and weights the loop factor.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import small_gicp
from pydantic import Field

from msa_slam.config import StageConfig
from msa_slam.errors import InputError
from msa_slam.registration.prepared import PreparedCloud
from msa_slam.types import validate_pose


class VerifierConfig(StageConfig):
    """Registration and acceptance parameters (metres, fractions); the run configuration's `verifier` section.
    `min_inlier_fraction` applies to both clouds (source points near the target and target points near the
    aligned source).

        `num_threads=1` keeps small_gicp's reductions in a fixed order, so identical runs accept identical loops.
    """

    SECTION: ClassVar[str] = "verifier"

    voxel_size: float = Field(0.5, gt=0)
    max_correspondence_distance: float = Field(1.0, gt=0)
    max_residual: float = Field(0.3, gt=0)
    min_inlier_fraction: float = Field(0.5, ge=0, le=1)
    min_inliers: int = Field(100, ge=0)
    coarse_to_fine: bool = True
    max_iterations: int = Field(50, ge=1)
    num_neighbors: int = Field(10, ge=3)
    num_threads: int = Field(1, ge=1)
    max_structure_residual: float = Field(0.15, gt=0)


STRUCTURE_MAX_NORMAL_Z = 0.7  # |normal z| below this: a non-horizontal surface (more than ~45 deg from the ground)
REJECTIONS = ("overlap", "inliers", "residual")  # the verifier's gates, in the order they are checked


@dataclass(frozen=True)
class Verification:
    """Outcome of one verification: `T_target_source` maps source-frame points into the target frame;
    `covariance` (6x6, rotation then translation) is its uncertainty; `rejected` names the first failed
    gate of REJECTIONS ("" when accepted)."""

    T_target_source: np.ndarray
    accepted: bool
    residual: float
    num_inliers: int
    inlier_fraction: float
    converged: bool
    target_fraction: float = float("nan")
    covariance: np.ndarray | None = None
    rejected: str = ""
    structure_residual: float = float("nan")


class Verifier:
    """Register two keyframe clouds (sensor frames) with GICP and gate the result on residual and inliers."""

    def __init__(self, config: VerifierConfig | None = None) -> None:
        self.config = config or VerifierConfig()

    def prepare(self, points: np.ndarray, where: str = "cloud") -> PreparedCloud:
        """`points` ready to be registered with this verifier's settings (its preprocessing made once, on use)."""
        return PreparedCloud(points, self.config.num_neighbors, self.config.num_threads, where)

    def verify(
        self,
        target: np.ndarray | PreparedCloud,
        source: np.ndarray | PreparedCloud,
        initial_guess: np.ndarray | None = None,
        strict: bool = False,
        coarse: bool = True,
    ) -> Verification:
        """Estimate T_target_source from `initial_guess` (identity by default) and decide acceptance (`strict`:
        with the structure gate too). The clouds are point arrays or `prepare`d ones (a keyframe's, shared by its
        candidates); `coarse=False` skips the coarse pass (the guess is a coarse registration already:
        registration.coarse). A cloud
        with fewer than `num_neighbors` points after voxel downsampling (a 1-point scan) cannot be registered:
        an InputError saying so, which loop closing records as the candidate's rejection (`sparse`)."""
        cfg = self.config
        tgt_cloud = target if isinstance(target, PreparedCloud) else self.prepare(target, "verification target cloud")
        src_cloud = source if isinstance(source, PreparedCloud) else self.prepare(source, "verification source cloud")
        T = np.eye(4) if initial_guess is None else validate_pose(initial_guess, "verification initial guess")
        stages = [(cfg.voxel_size, cfg.max_correspondence_distance)]
        if cfg.coarse_to_fine and coarse:
            # A coarse pass with a wide correspondence radius pulls in guesses that are metres off.
            stages.insert(0, (2.0 * cfg.voxel_size, 3.0 * cfg.max_correspondence_distance))
        converged = False
        for voxel, max_dist in stages:
            (tgt, tree), (src, src_tree) = tgt_cloud.at(voxel), src_cloud.at(voxel)
            if tgt.size() < cfg.num_neighbors or src.size() < cfg.num_neighbors:
                raise InputError(
                    f"verification clouds too sparse after {voxel} m voxels "
                    f"(target {tgt.size()} points, source {src.size()}; need >= {cfg.num_neighbors})"
                )
            result = small_gicp.align(
                tgt,
                src,
                tree,
                T,
                registration_type="GICP",
                max_correspondence_distance=max_dist,
                num_threads=cfg.num_threads,
                max_iterations=cfg.max_iterations,
            )
            T = np.asarray(result.T_target_source, dtype=np.float64)
            converged = bool(result.converged)
        matches = _Matches(tgt, tree, src, T, cfg.max_correspondence_distance)
        residual, num_inliers = matches.point_to_plane_residual()
        fraction = num_inliers / src.size()
        target_fraction = _covered_fraction(tgt, src_tree, T, cfg.max_correspondence_distance)
        structure = matches.structure_residual() if strict else float("nan")
        failed = {
            "overlap": min(fraction, target_fraction) < cfg.min_inlier_fraction,
            "inliers": num_inliers < cfg.min_inliers,
            "residual": not residual < cfg.max_residual or strict and not structure <= cfg.max_structure_residual,
        }
        rejected = next((gate for gate in REJECTIONS if failed[gate]), "")
        covariance = registration_covariance(np.asarray(result.H), result.error, result.num_inliers)
        return Verification(
            T,
            not rejected,
            residual,
            num_inliers,
            float(fraction),
            converged,
            target_fraction,
            covariance,
            rejected,
            structure,
        )


def _covered_fraction(
    target: small_gicp.PointCloud, source_tree: small_gicp.KdTree, T: np.ndarray, max_distance: float
) -> float:
    """Fraction of target points with an aligned source point within `max_distance` (searched in the source's
    frame: its kd-tree is the prepared cloud's)."""
    _, _, near = nearest_within(source_tree, target.points()[:, :3], np.linalg.inv(T), max_distance)
    return float(near.mean())


def nearest_within(
    tree: small_gicp.KdTree, points: np.ndarray, T: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`points` moved by T, the index of each one's nearest point in `tree`, and whether that point is within
    `radius`. Only the distances decide: a point without a neighbour has the largest double as its distance (and
    an index that is no point's)."""
    moved = points @ T[:3, :3].T + T[:3, 3]
    idx, sq_dist = tree.batch_nearest_neighbor_search(moved)
    return moved, np.asarray(idx), np.fromiter(sq_dist, np.float64, len(moved)) <= radius**2


class _Matches:
    """The aligned source points and their nearest target points, searched once for both the residual and the
    structure check (a point's nearest neighbour does not depend on the other points searched with it)."""

    def __init__(
        self,
        target: small_gicp.PointCloud,
        tree: small_gicp.KdTree,
        source: small_gicp.PointCloud,
        T: np.ndarray,
        max_distance: float,
    ) -> None:
        self.target, self.source, self.T = target, source, T
        self.moved, self.idx, self.inliers = nearest_within(tree, source.points()[:, :3], T, max_distance)

    def point_to_plane_residual(self) -> tuple[float, int]:
        """RMS point-to-plane distance of inlier correspondences (inf when there are none) and their count."""
        inliers = self.inliers
        if not inliers.any():
            return float("inf"), 0
        nearest = self.idx[inliers]
        normals = self.target.normals()[nearest, :3]
        offsets = self.moved[inliers] - self.target.points()[nearest, :3]
        plane = np.einsum("ij,ij->i", normals, offsets)
        return float(np.sqrt(np.mean(plane**2))), int(inliers.sum())

    def structure_residual(self) -> float:
        """Median point-to-plane distance of the source's inliers on non-horizontal surfaces (inf without any)."""
        upright = np.abs(self.source.normals()[:, :3] @ self.T[2, :3]) < STRUCTURE_MAX_NORMAL_Z
        inliers = self.inliers[upright]
        if not inliers.any():
            return float("inf")
        nearest = self.idx[upright][inliers]
        offsets = self.moved[upright][inliers] - self.target.points()[nearest, :3]
        return float(np.median(np.abs(np.einsum("ij,ij->i", self.target.normals()[nearest, :3], offsets))))


def registration_covariance(hessian: np.ndarray, error: float, num_inliers: int) -> np.ndarray:
    """Covariance of a GICP estimate (small_gicp: H = J^T M J at the solution, error = 0.5 sum r^T M r,
    tangent order rotation then translation): H^-1 scaled by the reduced chi-square of the residuals,
    since GICP's normalised point covariances are not calibrated. Infinite along directions H does not
    constrain (bounded_covariance caps them)."""
    dof = max(3 * int(num_inliers) - 6, 1)
    scale = max(2.0 * float(error) / dof, 1e-12)
    w, v = np.linalg.eigh(0.5 * (hessian + hessian.T))
    inv = np.where(w > 1e-12 * max(w.max(), 1e-300), 1.0 / np.maximum(w, 1e-300), 1e12)
    return scale * (v * inv) @ v.T
