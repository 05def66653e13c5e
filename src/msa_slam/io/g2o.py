"""The pose graph as a g2o file (g2o_viewer, GTSAM's readG2o and most SLAM back ends read it): keyframe
vertices at their optimised poses and every between factor the optimiser had, with its own information
matrix (drift-scaled odometry, registration-covariance loops).

gtsam.writeG2o refuses robust noise models, so the factors are written here: a robust loop factor is
written with its Gaussian part and the kernel named in a header comment (g2o files carry no kernel); the prior on
the first keyframe becomes `FIX`. Information is reordered from GTSAM's (rotation, translation) tangent
order to g2o's (translation, rotation), as gtsam's own writer does."""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

G2O_ORDER = [3, 4, 5, 0, 1, 2]  # g2o (x, y, z, rx, ry, rz) from GTSAM's (rx, ry, rz, x, y, z)


def _pose_fields(pose: np.ndarray) -> str:
    q = Rotation.from_matrix(pose[:3, :3]).as_quat()  # x y z w, as g2o's SE3:QUAT expects
    return " ".join(f"{round(v, 9) + 0.0:.9f}" for v in (*pose[:3, 3], *q))  # no "-0.000000000"


def _information(noise) -> str:
    """Upper triangle of the factor's 6x6 information matrix in g2o's order."""
    r = noise.R()
    info = (r.T @ r)[np.ix_(G2O_ORDER, G2O_ORDER)]
    return " ".join(f"{info[i, j] + 0.0:.9g}" for i in range(6) for j in range(i, 6))


def format_g2o(keys: Sequence[int] | np.ndarray, poses: np.ndarray, factors: gtsam.NonlinearFactorGraph) -> str:
    """g2o text: VERTEX_SE3:QUAT per key at `poses`, EDGE_SE3:QUAT per between factor of `factors` (in their
    order), FIX of the first key."""
    lines = [f"VERTEX_SE3:QUAT {int(k)} {_pose_fields(p)}" for k, p in zip(keys, poses)]
    kernels = set()
    for i in range(factors.size()):
        factor = factors.at(i)
        if not isinstance(factor, gtsam.BetweenFactorPose3):
            continue  # the prior: FIX below
        a, b = factor.keys()
        noise = factor.noiseModel()
        if isinstance(noise, gtsam.noiseModel.Robust):
            kernels.add(type(noise.robust()).__name__.lower())
            noise = noise.noise()
        lines.append(f"EDGE_SE3:QUAT {a} {b} {_pose_fields(factor.measured().matrix())} {_information(noise)}")
    if len(keys):
        lines.append(f"FIX {int(keys[0])}")
    if kernels:
        lines.insert(0, f"# loop edges had a robust {'/'.join(sorted(kernels))} kernel (not expressible in g2o)")
    return "\n".join(lines) + "\n"
