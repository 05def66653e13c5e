"""Convert KITTI odometry ground truth (cam0 poses) into the compact LiDAR-frame files the package ships.

KITTI (Geiger, Lenz, Urtasun, "Are we ready for autonomous driving?", CVPR 2012; CC BY-NC-SA 3.0)
gives ground truth as cam0 poses; with the Velodyne->cam0 extrinsic Tr, the LiDAR pose is
T_world_lidar = Tr^-1 @ P_cam0 @ Tr (the world frame becomes the first LiDAR frame). The shipped files
store translations and unit quaternions as float32 plus the timestamps, so the five trajectories take a
few hundred KB. Regenerate with `python -m msa_slam.sim.kitti_data /path/to/kitti_gt`. Other sequences need
no conversion: `msa-slam simulate --trajectory NN.txt --times NN_times.txt --calib calib.txt` reads KITTI's
files directly (sim.trajectories.read_trajectory, the same cam0 -> LiDAR conversion).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from msa_slam.errors import InputError
from msa_slam.io.poses import read_poses

KITTI_SEQUENCES = ("00", "05", "06", "07", "09")
DATA_DIR = Path(__file__).resolve().parents[1] / "data" / "trajectories"


def read_calib_tr(calib_file: Path, sequence: str) -> np.ndarray:
    """The (4, 4) Velodyne->cam0 extrinsic of `sequence` from a calib file of `NN v1 .. v12` lines."""
    for line in Path(calib_file).read_text().splitlines():
        parts = line.split()
        if parts and parts[0] == sequence:
            if len(parts) != 13:
                raise InputError(f"{calib_file}: sequence {sequence} has {len(parts) - 1} values, expected 12")
            tr = np.eye(4)
            tr[:3, :4] = np.array(parts[1:], dtype=np.float64).reshape(3, 4)
            return tr
    raise InputError(f"{calib_file}: no Tr line for sequence {sequence}")


def cam0_to_lidar(poses_cam0: np.ndarray, tr: np.ndarray) -> np.ndarray:
    """LiDAR-frame poses Tr^-1 @ P @ Tr of an (N, 4, 4) cam0 pose stack."""
    return np.linalg.inv(tr) @ poses_cam0 @ tr


def convert(gt_dir: Path, out_dir: Path = DATA_DIR) -> list[Path]:
    """Write kitti_NN.npz (translations, quaternions xyzw, times; float32) for every shipped sequence."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for seq in KITTI_SEQUENCES:
        poses_cam0, _ = read_poses(gt_dir / f"{seq}.txt", fmt="kitti")
        poses = cam0_to_lidar(poses_cam0, read_calib_tr(gt_dir / "calib.txt", seq))
        times = np.loadtxt(gt_dir / f"{seq}_times.txt", dtype=np.float64).reshape(-1)
        if len(times) != len(poses):
            raise InputError(f"{gt_dir}/{seq}_times.txt: {len(times)} times for {len(poses)} poses")
        target = out_dir / f"kitti_{seq}.npz"
        np.savez_compressed(
            target,
            translations=poses[:, :3, 3].astype(np.float32),
            quaternions=Rotation.from_matrix(poses[:, :3, :3]).as_quat().astype(np.float32),
            times=times.astype(np.float32),
        )
        written.append(target)
    return written


if __name__ == "__main__":
    for path in convert(Path(sys.argv[1])):
        print(path)
