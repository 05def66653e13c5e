"""Inputs a user must be able to trust: a bad calib.txt, too few points to register, a grid's cost
stated before it starts, and no compile process left running after its demo is killed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msa_slam.datasets import open_dataset
from msa_slam.errors import InputError
from msa_slam.io.poses import format_kitti


def _kitti_with_tr(root: Path, tr_line: str) -> Path:
    """A 3-scan KITTI-layout sequence whose (rotating) poses are converted by the given calib.txt Tr line."""
    seq = root / "07"
    (seq / "velodyne").mkdir(parents=True)
    for k in range(3):
        np.random.default_rng(k).normal(size=(50, 4)).astype(np.float32).tofile(seq / "velodyne" / f"{k:06d}.bin")
    (seq / "calib.txt").write_text("P0: " + " ".join(["0"] * 12) + "\n" + tr_line + "\n")
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("z", np.arange(3)[:, None] * 0.3).as_matrix()
    poses[:, 0, 3] = np.arange(3)
    (seq / "poses.txt").write_text(format_kitti(poses))
    return seq


def test_a_non_rigid_tr_is_named_in_calib_txt_not_as_a_pose(tmp_path):
    """A scaled Tr was reported as "poses: frame 1 is not a rigid transform", naming neither calib.txt nor Tr."""
    seq = _kitti_with_tr(tmp_path, "Tr: 1.1 0 0 0 0 1 0 0 0 0 1 0")
    calib = seq / "calib.txt"
    with pytest.raises(InputError) as err:
        open_dataset(seq)
    assert str(err.value) == (f"{calib}:2: Tr (the Velodyne->camera extrinsic) is not a rigid transform "
                              "(|R R^T - I| = 2.10e-01, det R = 1.100000); it must be a rotation and a translation")

