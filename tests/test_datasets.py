"""Dataset readers on tiny sequences written into tmp_path; every bad layout names its file."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from helpers.scans import write_bin
from scipy.spatial.transform import Rotation

from msa_slam.datasets import Frame, open_dataset, read_cloud, read_pcd
from msa_slam.errors import InputError
from msa_slam.io.poses import format_kitti, write_poses

TR = np.eye(4)
TR[:3, :3] = Rotation.from_euler("zyx", [-90, 0, -90], degrees=True).as_matrix()  # LiDAR x-forward -> camera z
TR[:3, 3] = [0.01, -0.05, -0.3]


def _points(k: int, n: int = 50) -> np.ndarray:
    rng = np.random.default_rng(k)
    return rng.normal(size=(n, 3)).astype(np.float32) * 10


def _lidar_poses(n: int) -> np.ndarray:
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n) * 1.5
    poses[:, :3, :3] = Rotation.from_euler("z", np.arange(n)[:, None] * 0.1).as_matrix()
    return poses


def _kitti(root: Path, n: int = 3, poses_in_sequence: bool = True) -> Path:
    seq = root / "sequences" / "07"
    for k in range(n):
        write_bin(seq / "velodyne" / f"{k:06d}.bin", _points(k))
    (seq / "calib.txt").write_text(
        "P0: " + " ".join(["0"] * 12) + "\nTr: " + " ".join(f"{v:.12e}" for v in TR[:3].ravel()) + "\n"
    )
    (seq / "times.txt").write_text("".join(f"{0.1 * k:.6f}\n" for k in range(n)))
    cam = TR @ _lidar_poses(n) @ np.linalg.inv(TR)
    pose_file = seq / "poses.txt" if poses_in_sequence else root / "poses" / "07.txt"
    pose_file.parent.mkdir(parents=True, exist_ok=True)
    pose_file.write_text(format_kitti(cam))
    return seq


@pytest.mark.parametrize("poses_in_sequence", [True, False])
def test_kitti_sequence_reads_scans_times_and_lidar_poses(tmp_path, poses_in_sequence):
    seq = open_dataset(_kitti(tmp_path, poses_in_sequence=poses_in_sequence))
    assert len(seq) == 3 and seq.name == "07"
    frame = seq[2]
    assert isinstance(frame, Frame) and frame.index == 2 and frame.time == pytest.approx(0.2)
    np.testing.assert_array_equal(frame.points, _points(2))
    np.testing.assert_allclose(frame.gt_pose, _lidar_poses(3)[2], atol=1e-9)
    assert [f.index for f in seq] == [0, 1, 2]
    with pytest.raises(IndexError):
        seq[3]


def test_kitti_scans_without_zero_padding_keep_their_numeric_order(tmp_path):
    seq = _kitti(tmp_path, n=12)
    for k in range(12):  # 0.bin ... 11.bin: string order would read 10.bin and 11.bin after 1.bin
        (seq / "velodyne" / f"{k:06d}.bin").rename(seq / "velodyne" / f"{k}.bin")
    frames = open_dataset(seq)
    for k in (2, 10, 11):
        np.testing.assert_array_equal(frames[k].points, _points(k))


def test_unreadable_velodyne_folder_is_named_as_unreadable(tmp_path, monkeypatch):
    """Not "no .bin scans": the folder is there but cannot be listed (the CLI prints permission denied)."""
    seq = _kitti(tmp_path)
    velodyne = seq / "velodyne"
    listdir = os.listdir

    def denied(path="."):
        if Path(path) == velodyne:
            raise PermissionError(13, "Permission denied", str(velodyne))
        return listdir(path)

    monkeypatch.setattr(os, "listdir", denied)
    with pytest.raises(PermissionError) as err:
        open_dataset(seq)
    assert err.value.filename == str(velodyne)


def test_hidden_files_are_not_scans(tmp_path):
    seq = _kitti(tmp_path)
    (seq / "velodyne" / "._000001.bin").write_bytes(b"\0" * 4096)  # a macOS resource fork
    assert len(open_dataset(seq)) == 3
    folder = tmp_path / "folder"
    folder.mkdir()
    for k in range(3):
        write_bin(folder / f"{k}.bin", _points(k))
    (folder / ".DS_Store.bin").write_bytes(b"\0" * 32)
    assert len(open_dataset(folder)) == 3


def test_kitti_errors_name_the_file(tmp_path):
    seq = _kitti(tmp_path)
    (seq / "poses.txt").write_text(format_kitti(_lidar_poses(2)))
    with pytest.raises(InputError, match=r"poses.txt: 2 poses but .*velodyne has 3 scans"):
        open_dataset(seq)
    (seq / "poses.txt").write_text(format_kitti(_lidar_poses(3)))
    (seq / "calib.txt").unlink()
    with pytest.raises(InputError, match="calib.txt: missing"):
        open_dataset(seq)
    with pytest.raises(InputError, match="no velodyne"):
        open_dataset(tmp_path, kind="kitti")
    with pytest.raises(InputError, match="dataset not found"):
        open_dataset(tmp_path / "nowhere")


def test_corrupt_and_empty_scans_stop_the_run_before_any_work(tmp_path):
    # The sizes of the scans a run selects are checked before odometry (select), not when frame 1 is reached.
    seq = _kitti(tmp_path)
    bad = seq / "velodyne" / "000001.bin"
    bad.write_bytes(b"\x00" * 20)
    with pytest.raises(InputError, match="000001.bin: 20 bytes is not a whole number"):
        open_dataset(seq).select()
    with pytest.raises(InputError, match="000001.bin: 20 bytes is not a whole number"):
        open_dataset(seq).select(first=1, count=1)
    bad.write_bytes(b"")
    with pytest.raises(InputError, match="000001.bin: scan file is empty"):
        open_dataset(seq).select()


def test_a_scan_cut_short_outside_the_selection_does_not_stop_a_run(tmp_path):
    """A last file cut short by a crashed recorder: `-n` (or --jump) that leaves it out still runs."""
    seq = _kitti(tmp_path, n=4)
    last = seq / "velodyne" / "000003.bin"
    last.write_bytes(last.read_bytes()[:100])
    part = open_dataset(seq).select(count=3)
    assert [f.index for f in part] == [0, 1, 2]
    np.testing.assert_array_equal(part[2].points, _points(2))
    assert len(open_dataset(seq).select(jump=3, count=1)) == 1  # scan 0 only
    with pytest.raises(InputError, match="000003.bin: 100 bytes is not a whole number"):
        open_dataset(seq).select(first=2)


def _as_float64(path: Path, points: np.ndarray) -> None:
    """A common mistake: x, y, z, r stored as float64 (32 bytes a point, still a multiple of 16)."""
    np.hstack([points, np.ones((len(points), 1))]).astype(np.float64).tofile(path)


@pytest.mark.parametrize("values", ["from_float32", "float64"])
def test_float64_scans_are_refused_when_a_run_selects_them_naming_the_file(tmp_path, values):
    seq = _kitti(tmp_path)
    for k in range(3):
        points = _points(k) if values == "from_float32" else np.random.default_rng(k).normal(size=(50, 3)) * 10
        _as_float64(seq / "velodyne" / f"{k:06d}.bin", points)
    with pytest.raises(InputError, match=r"000000.bin: coordinate .* beyond any sensor's range .*float32"):
        open_dataset(seq).select()  # the first scan selected is read then, before any long work


def test_each_scan_is_checked_when_read(tmp_path):
    seq = _kitti(tmp_path)
    opened = open_dataset(seq)
    _as_float64(seq / "velodyne" / "000002.bin", _points(2))
    assert len(opened[1].points) == 50
    with pytest.raises(InputError, match="000002.bin: coordinate"):
        opened[2]


def test_implausible_scan_values(tmp_path):
    path = tmp_path / "scan.bin"
    millimetres = (np.random.default_rng(0).normal(size=(50, 4)) * 5000).astype(np.int32)
    millimetres.tofile(path)  # integers read as float32 are subnormal numbers
    with pytest.raises(InputError, match=r"scan.bin: 100 % of the points have coordinates below 1e-20"):
        read_cloud(path)
    points = _points(0)
    points[3, 1] = np.inf
    write_bin(path, points)
    with pytest.raises(InputError, match="scan.bin: coordinate inf m is beyond"):
        read_cloud(path)
    points[:, 0] = np.nan
    write_bin(path, points)
    with pytest.raises(InputError, match="scan.bin: scan has no finite points"):
        read_cloud(path)
    points = _points(0)
    points[[4, 7]] = np.nan  # missing returns marked NaN are dropped, the rest is a valid scan
    write_bin(path, points)
    np.testing.assert_array_equal(read_cloud(path), np.delete(_points(0), [4, 7], axis=0))


@pytest.mark.parametrize(
    ("times", "line", "problem"),
    [
        (["0.0", "nan", "0.2"], 2, "time nan is not a finite number"),
        (["0.0", "0.1", "0.1"], 3, r"time 0.1 repeats the previous one \(0.1\)"),
        (["0.0", "0.2", "0.1"], 3, r"time 0.1 is before the previous one \(0.2\)"),
        (["0.0", "", "0.1", "abc"], 4, "'abc' is not a time in seconds"),
    ],
)
def test_bad_times_name_the_line(tmp_path, times, line, problem):
    seq = _kitti(tmp_path)
    (seq / "times.txt").write_text("\n".join(times) + "\n")
    with pytest.raises(InputError, match=rf"times.txt:{line}: {problem}"):
        open_dataset(seq)


def test_times_must_match_the_scans(tmp_path):
    seq = _kitti(tmp_path)
    (seq / "times.txt").write_text("0.0\n0.1\n")
    with pytest.raises(InputError, match=r"times.txt: 2 times but .*velodyne has 3 scans"):
        open_dataset(seq)


def test_pose_file_times_must_increase(tmp_path):
    for k in range(3):
        write_bin(tmp_path / f"{k}.bin", _points(k))
    write_poses(tmp_path / "poses.tum", _lidar_poses(3), fmt="tum", times=np.array([1.0, 1.1, 1.1]))
    with pytest.raises(InputError, match=r"poses.tum: pose 3: time 1.1 repeats the previous one"):
        open_dataset(tmp_path / "", poses=tmp_path / "poses.tum")


def test_folder_of_ply_with_tum_poses(tmp_path):
    import trimesh

    for k in range(3):
        trimesh.PointCloud(_points(k).astype(np.float64)).export(tmp_path / f"scan_{k + 8}.ply")
    poses = _lidar_poses(3)
    write_poses(tmp_path / "poses.tum", poses, fmt="tum", times=np.array([1.0, 1.1, 1.2]))
    seq = open_dataset(tmp_path, poses=tmp_path / "poses.tum")
    assert [f.name for f in seq.scan_files] == ["scan_8.ply", "scan_9.ply", "scan_10.ply"]  # natural order
    np.testing.assert_allclose(seq[1].points, _points(1), atol=1e-6)
    np.testing.assert_allclose(seq[2].gt_pose, poses[2], atol=1e-6)
    assert seq[2].time == pytest.approx(1.2)
    write_poses(tmp_path / "short.txt", poses[:2])
    with pytest.raises(InputError, match="short.txt: 2 poses but .* has 3 scans"):
        open_dataset(tmp_path, poses=tmp_path / "short.txt")


def test_folder_errors(tmp_path):
    with pytest.raises(InputError, match="no scan files"):
        open_dataset(tmp_path)
    write_bin(tmp_path / "a.bin", _points(0))
    (tmp_path / "b.pcd").write_text("x")
    with pytest.raises(InputError, match="mixes scan formats"):
        open_dataset(tmp_path)
    with pytest.raises(InputError, match="unsupported scan format"):
        read_cloud(tmp_path / "c.xyz")


def _pcd_header(n: int, data: str, extra: bool) -> str:
    fields = "x y z intensity" if extra else "x y z"
    sizes = "4 4 4 2" if extra else "4 4 4"
    types = "F F F U" if extra else "F F F"
    return (
        f"# .PCD v0.7\nVERSION 0.7\nFIELDS {fields}\nSIZE {sizes}\nTYPE {types}\n"
        f"COUNT {' '.join(['1'] * len(fields.split()))}\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {n}\nDATA {data}\n"
    )


def test_pcd_ascii_and_binary(tmp_path):
    pts = _points(3, n=7)
    ascii_file = tmp_path / "a.pcd"
    ascii_file.write_text(_pcd_header(7, "ascii", False) + "".join(f"{x} {y} {z}\n" for x, y, z in pts))
    np.testing.assert_allclose(read_pcd(ascii_file), pts, atol=1e-5)
    record = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<u2")])
    table = np.zeros(7, dtype=record)
    table["x"], table["y"], table["z"] = pts.T
    binary_file = tmp_path / "b.pcd"
    binary_file.write_bytes(_pcd_header(7, "binary", True).encode() + table.tobytes())
    np.testing.assert_array_equal(read_pcd(binary_file), pts.astype(np.float64))
    binary_file.write_bytes(_pcd_header(7, "binary", True).encode() + table.tobytes()[:-10])
    with pytest.raises(InputError, match="b.pcd: PCD data is truncated"):
        read_pcd(binary_file)
    (tmp_path / "c.pcd").write_text(_pcd_header(7, "binary_compressed", False))
    with pytest.raises(InputError, match="binary_compressed"):
        read_pcd(tmp_path / "c.pcd")


def test_mulran_through_kiss_loader(tmp_path):
    stamps = [1000, 2000, 3000]
    for k, stamp in enumerate(stamps):
        write_bin(tmp_path / "Ouster" / f"{stamp}.bin", _points(k))
    rows = []
    for stamp in stamps:  # timestamp, then a row-major 3x4 pose moving 1 m along x per scan
        pose = np.eye(4)[:3]
        pose[0, 3] = stamp / 1000.0
        rows.append([stamp, *pose.ravel()])
    np.savetxt(tmp_path / "global_pose.csv", np.array(rows), delimiter=",")
    seq = open_dataset(tmp_path, kind="mulran")
    assert len(seq) == 3
    np.testing.assert_array_equal(seq[1].points, _points(1))
    # kiss_icp expresses MulRan ground truth relative to the first pose, in the LiDAR frame.
    assert np.linalg.norm(seq[2].gt_pose[:3, 3]) == pytest.approx(2.0, abs=1e-3)
    (tmp_path / "global_pose.csv").unlink()
    assert open_dataset(tmp_path, kind="mulran").gt_poses is None  # a recording without ground truth
    with pytest.raises(InputError, match="unknown dataset loader"):
        open_dataset(tmp_path, kind="nuscenes-ish")


def _mulran_pose_file(folder: Path, stamps: np.ndarray, poses: np.ndarray) -> None:
    """MulRan's global_pose.csv: nanosecond time, then the row-major 3x4 pose."""
    rows = np.column_stack([stamps, poses[:, :3, :4].reshape(len(poses), 12)])
    np.savetxt(folder / "global_pose.csv", rows, delimiter=",", fmt="%.17g")


def test_mulran_pose_file_in_the_ouster_frame_is_flagged(tmp_path):
    """MulRan's global_pose.csv holds the vehicle base's poses; the loader turns them into the Ouster's
    (mounted facing backwards). Ouster-frame poses given instead come out turned ~180 deg about z, which no
    alignment removes: the front end says so, naming the likely cause."""
    from msa_slam.evaluation import ate
    from msa_slam.evaluation.sanity import frontend_warnings

    n = 40
    stamps = 1_600_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 100_000_000
    for k, stamp in enumerate(stamps):
        write_bin(tmp_path / "sensor_data" / "Ouster" / f"{stamp}.bin", _points(k, 5))
    yaw = 0.3 + 0.02 * np.arange(n)  # a car driving forward (base x) on a left curve, 1 m a frame, in UTM
    base = np.tile(np.eye(4), (n, 1, 1))
    base[:, :3, :3] = Rotation.from_euler("z", yaw[:, None]).as_matrix()
    base[:, 0, 3] = 350_000 + np.cumsum(np.cos(yaw))
    base[:, 1, 3] = 4_000_000 + np.cumsum(np.sin(yaw))
    _mulran_pose_file(tmp_path, stamps, base)
    seq = open_dataset(tmp_path, kind="mulran")
    ouster = seq.gt_poses  # what LiDAR odometry of these scans would find
    times = seq.times
    assert not [w for w in frontend_warnings(seq.gt_poses, ouster, times) if "180 deg" in w]

    _mulran_pose_file(tmp_path, stamps, ouster)  # Ouster-frame poses where base-frame ones belong
    turned = open_dataset(tmp_path, kind="mulran").gt_poses
    assert ate(ouster, turned).rotation_rmse > 170  # the silent failure: a ~180 deg rotation "error"
    (warning,) = [w for w in frontend_warnings(turned, ouster, times) if "180 deg" in w]
    assert f"on {n - 1} of the {n - 1} steps where both move" in warning
    assert "global_pose.csv must hold the vehicle base's poses" in warning and "Ouster frame" in warning


def test_apollo_layout_without_open3d(tmp_path):
    (tmp_path / "pcds").mkdir()
    for k in range(3):
        pts = _points(k, n=5)
        (tmp_path / "pcds" / f"{k + 1}.pcd").write_text(
            _pcd_header(5, "ascii", False) + "".join(f"{x} {y} {z}\n" for x, y, z in pts)
        )
    (tmp_path / "poses").mkdir()
    lines = [f"{k} {k * 0.1} {10 + 2 * k} 5 0 0 0 0 1\n" for k in range(3)]  # index time x y z qx qy qz qw
    (tmp_path / "poses" / "gt_poses.txt").write_text("".join(lines))
    seq = open_dataset(tmp_path, kind="apollo")
    assert [f.name for f in seq.scan_files] == ["1.pcd", "2.pcd", "3.pcd"]
    np.testing.assert_allclose(seq[2].points, _points(2, n=5), atol=1e-5)
    np.testing.assert_allclose(seq[2].gt_pose[:3, 3], [4.0, 0.0, 0.0])  # relative to the first pose


# --- per-point times ---------------------------------------------------------------------


def test_kitti_frames_derive_point_times_from_azimuth(tmp_path):
    seq = _kitti(tmp_path)
    ahead_left_right_behind = np.array(
        [[10, 0, 0], [0, 10, 0], [0, -10, 0], [-10, 1e-3, 0], [-10, -1e-3, 0]], np.float32
    )
    write_bin(seq / "velodyne" / "000001.bin", ahead_left_right_behind)
    frame = open_dataset(seq)[1]
    # HDL-64 at 10 Hz, clockwise from the back: forward at mid-sweep (the scan's timestamp), as kiss-icp
    np.testing.assert_allclose(frame.timestamps, [0.05, 0.025, 0.075, 0.0, 0.1], atol=1e-5)
    times = open_dataset(seq)[0].timestamps
    assert times.shape == (50,) and times.dtype == np.float64 and np.all((times >= 0) & (times < 0.1))


def test_kitti_frames_read_stored_point_times(tmp_path):
    seq = _kitti(tmp_path)
    stored = [np.linspace(0.0, 0.099, 50, dtype=np.float32) + k * 1e-4 for k in range(3)]
    (seq / "velodyne_times").mkdir()
    for k, times in enumerate(stored):
        np.save(seq / "velodyne_times" / f"{k:06d}.npy", times)
    frames = list(open_dataset(seq))
    for frame, times in zip(frames, stored):
        assert frame.timestamps.dtype == np.float64
        np.testing.assert_array_equal(frame.timestamps, times)
    np.testing.assert_array_equal(frames[2].points, _points(2))


def test_kitti_stored_point_times_errors_name_the_file(tmp_path):
    seq = _kitti(tmp_path)
    (seq / "velodyne_times").mkdir()
    for k in range(3):
        np.save(seq / "velodyne_times" / f"{k:06d}.npy", np.zeros(50 if k != 1 else 49, np.float32))
    data = open_dataset(seq)
    with pytest.raises(InputError, match=r"000001.npy: \(49,\) per-point times for a scan of 50 points"):
        data[1]
    (seq / "velodyne_times" / "000002.npy").unlink()
    with pytest.raises(InputError, match=r"velodyne_times/000002.npy: missing"):
        open_dataset(seq)
    (seq / "velodyne_times" / "000002.npy").write_text("not numpy")
    with pytest.raises(InputError, match="000002.npy: cannot read per-point times"):
        open_dataset(seq)[2]


def test_stored_point_times_follow_the_points_a_reader_keeps(tmp_path):
    seq = _kitti(tmp_path)
    points = _points(0, n=4)
    points[2] = np.nan  # drivers mark missing returns so; the reader drops the row
    write_bin(seq / "velodyne" / "000000.bin", points)
    (seq / "velodyne_times").mkdir()
    for k in range(3):
        np.save(seq / "velodyne_times" / f"{k:06d}.npy", np.arange(4 if k == 0 else 50, dtype=np.float32) * 1e-3)
    frame = open_dataset(seq)[0]
    assert len(frame.points) == 3
    np.testing.assert_allclose(frame.timestamps, [0.0, 1e-3, 3e-3])
