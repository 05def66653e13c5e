"""Each supported input on a small recording written here in that dataset's exact layout (bags
written with rosbags): the loader is found from the layout, scans, times, ground truth and per-point times
come through, and a wrong layout names what was expected where."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from helpers.scans import write_bin

from msa_slam.datasets import LOADERS, detect_loader, open_dataset
from msa_slam.datasets.kiss_loaders import OUSTER_COLUMNS, OUSTER_ROWS
from msa_slam.datasets.lzf import lzf_decompress
from msa_slam.datasets.options import SourceOptions
from msa_slam.datasets.pcd import read_timed_pcd
from msa_slam.errors import InputError
from msa_slam.io.poses import format_kitti
from msa_slam.sources import open_sequence

N = 4


def _points(k: int, n: int = 40) -> np.ndarray:
    return (np.random.default_rng(k).normal(size=(n, 3)) * 10).astype(np.float32)


def _poses(n: int = N) -> np.ndarray:
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n) * 2.0
    return poses


def lzf_compress(data: bytes) -> bytes:
    """A greedy LZF encoder (the format lzf.py documents) with back references, for writing test files."""
    out, literal, i, seen = bytearray(), bytearray(), 0, {}

    def flush():
        for s in range(0, len(literal), 32):
            chunk = literal[s : s + 32]
            out.extend([len(chunk) - 1, *chunk])
        literal.clear()

    while i < len(data):
        ref = seen.get(data[i : i + 3]) if i + 3 <= len(data) else None
        seen[data[i : i + 3]] = i
        if ref is not None and i - ref - 1 < 8192:
            length = 3
            while i + length < len(data) and length < 264 and data[ref + length] == data[i + length]:
                length += 1
            flush()
            off, n = i - ref - 1, length - 2
            if n < 7:
                out.extend([(n << 5) | (off >> 8), off & 0xFF])
            else:
                out.extend([(7 << 5) | (off >> 8), n - 7, off & 0xFF])
            i += length
        else:
            literal.append(data[i])
            i += 1
    flush()
    return bytes(out)


def _pcd(path: Path, points: np.ndarray, times: np.ndarray, mode: str) -> None:
    """A PCD file with x y z (float32) and t (uint32 ns) fields in encoding `mode`."""
    n = len(points)
    header = (
        f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z t\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH {n}\n"
        f"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {mode}\n"
    ).encode()
    t = times.astype(np.uint32)
    if mode == "ascii":
        body = "".join(f"{x} {y} {z} {s}\n" for (x, y, z), s in zip(points.tolist(), t.tolist())).encode()
    elif mode == "binary":
        rows = np.empty(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("t", "<u4")])
        rows["x"], rows["y"], rows["z"], rows["t"] = points[:, 0], points[:, 1], points[:, 2], t
        body = rows.tobytes()
    else:  # binary_compressed: each field's values in turn, LZF-compressed, after two size words
        plain = b"".join(np.ascontiguousarray(c).tobytes() for c in (*points.T.astype("<f4"), t.astype("<u4")))
        packed = lzf_compress(plain)
        body = np.array([len(packed), len(plain)], "<u4").tobytes() + packed
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(header + body)


def test_lzf_round_trip_with_overlapping_back_references():
    data = bytes(500) + bytes(range(256)) * 3 + b"abcabcabcabc" * 40
    packed = lzf_compress(data)
    assert len(packed) < len(data) / 3  # the encoder used back references, some overlapping (runs)
    assert lzf_decompress(packed, len(data)) == data
    with pytest.raises(InputError, match="decodes to"):
        lzf_decompress(packed, len(data) + 1, "f.pcd")
    with pytest.raises(InputError, match="corrupt LZF stream"):
        lzf_decompress(bytes([0xE0, 0x05, 0xFF]), 10, "f.pcd")  # a back reference before the start


@pytest.mark.parametrize("mode", ["ascii", "binary", "binary_compressed"])
def test_pcd_every_encoding_with_point_times(tmp_path, mode):
    points = np.round(_points(1, 300), 3)
    points[::7] = points[0]  # repeated values, so the compressed stream has back references
    times = np.arange(300) * 1000 + 5_000
    _pcd(tmp_path / "s.pcd", points, times, mode)
    read, stamps = read_timed_pcd(tmp_path / "s.pcd")
    np.testing.assert_allclose(read, points, atol=1e-6)
    np.testing.assert_allclose(stamps, np.arange(300) * 1e-6)  # integer t counts ns, from the earliest point


def test_pcd_folder_with_tum_ground_truth_matched_by_time(tmp_path):
    folder = tmp_path / "scans"
    for k in range(N):
        _pcd(folder / f"{k}.pcd", _points(k), np.arange(40) * 100, "binary_compressed")
    poses = _poses(2 * N)
    times = 100.0 + 0.05 * np.arange(2 * N)  # twice the scan rate: every other pose matches a scan
    quat = np.tile([0, 0, 0, 1.0], (2 * N, 1))
    rows = np.column_stack([times, poses[:, :3, 3], quat])
    (tmp_path / "gt.tum").write_text("".join(" ".join(f"{v:.9f}" for v in r) + "\n" for r in rows))
    (tmp_path / "scan_times.tum").write_text("".join(" ".join(f"{v:.9f}" for v in r) + "\n" for r in rows[::2]))
    seq = open_dataset(folder, poses=tmp_path / "scan_times.tum")  # one pose a scan: its times are the scans'
    assert detect_loader(folder) == "folder" and seq[0].timestamps is not None
    np.testing.assert_allclose(seq.times, times[::2])
    seq2 = open_dataset(folder)
    assert seq2.gt_poses is None  # no ground truth: opens anyway


def test_ply_folder_with_kitti_ground_truth(tmp_path):
    import trimesh

    for k in range(N):
        trimesh.PointCloud(_points(k)).export(tmp_path / "scans" / f"{k:03d}.ply") if (tmp_path / "scans").mkdir(
            exist_ok=True
        ) is None else None
    (tmp_path / "gt.txt").write_text(format_kitti(_poses()))
    seq = open_dataset(tmp_path / "scans", poses=tmp_path / "gt.txt")
    np.testing.assert_allclose(seq.gt_poses, _poses())
    np.testing.assert_allclose(seq[2].points, _points(2), atol=1e-5)
    (tmp_path / "short.txt").write_text(format_kitti(_poses(2)))
    with pytest.raises(InputError, match="short.txt: 2 poses but .* has 4 scans"):
        open_dataset(tmp_path / "scans", poses=tmp_path / "short.txt")


def _mulran(seq: Path, n: int = N) -> None:
    stamps = 1_600_000_000_000_000_000 + np.arange(n) * 100_000_000
    for k, stamp in enumerate(stamps):
        write_bin(seq / "sensor_data" / "Ouster" / f"{stamp}.bin", _points(k))
    rows = [[s, *np.eye(4)[:3].ravel()] for s in stamps]
    for k, row in enumerate(rows):
        row[4] = 1.5 * k  # x translation of the 3x4 pose
    np.savetxt(seq / "global_pose.csv", np.array(rows), delimiter=",", fmt="%.17g")


def test_mulran_as_shipped_from_its_sequence_or_its_root(tmp_path):
    _mulran(tmp_path / "KAIST01")
    seq = open_dataset(tmp_path / "KAIST01")
    assert detect_loader(tmp_path / "KAIST01") == "mulran" and len(seq) == N
    assert np.linalg.norm(seq.gt_poses[3, :3, 3]) == pytest.approx(4.5, abs=1e-3)
    assert seq.times[1] - seq.times[0] == pytest.approx(0.1, abs=1e-6)
    np.testing.assert_allclose(open_dataset(tmp_path, sequence="KAIST01")[1].points, _points(1))
    with pytest.raises(InputError, match="no sequence 'KAIST02'.*KAIST01"):
        open_dataset(tmp_path, sequence="KAIST02")


def test_ouster_scans_carry_column_times(tmp_path):
    write_bin(tmp_path / "Ouster" / "1000000000.bin", _points(0, OUSTER_ROWS * OUSTER_COLUMNS))
    write_bin(tmp_path / "Ouster" / "1100000000.bin", _points(1, 10))
    seq = open_dataset(tmp_path, kind="mulran")
    stamps = seq[0].timestamps
    assert stamps[0] == 0 and stamps[OUSTER_ROWS] > 0 and stamps[-1] == pytest.approx(0.1 * 1023 / 1024)
    assert seq[1].timestamps is None  # a scan of another size: no times, as in kiss-icp


def test_helipr_sensor_records_and_ground_truth(tmp_path):
    record = np.dtype(
        [
            ("x", "<f4"),
            ("y", "<f4"),
            ("z", "<f4"),
            ("intensity", "<f4"),
            ("t", "<u4"),
            ("reflectivity", "<u2"),
            ("ring", "<u2"),
            ("ambient", "<u2"),
        ]
    )
    assert record.itemsize == 26  # kiss-icp's "=ffffIHHH"
    stamps = 1_690_000_000_000_000_000 + np.arange(N) * 100_000_000
    for k, stamp in enumerate(stamps):
        rows = np.zeros(40, record)
        pts = _points(k)
        rows["x"], rows["y"], rows["z"], rows["t"] = pts[:, 0], pts[:, 1], pts[:, 2], np.arange(40) * 2_500_000
        (tmp_path / "LiDAR" / "Ouster").mkdir(parents=True, exist_ok=True)
        rows.tofile(tmp_path / "LiDAR" / "Ouster" / f"{stamp}.bin")
    (tmp_path / "LiDAR_GT").mkdir()
    gt = "".join(f"{s} {1.5 * k} 0 0 0 0 0 1\n" for k, s in enumerate(stamps))
    (tmp_path / "LiDAR_GT" / "global_Ouster_gt.txt").write_text(gt)
    with pytest.raises(InputError, match="--sequence naming its LiDAR.*found under .*: Ouster"):
        open_dataset(tmp_path)
    seq = open_dataset(tmp_path, sequence="Ouster")
    np.testing.assert_allclose(seq[1].points, _points(1))
    np.testing.assert_allclose(seq[1].timestamps, np.arange(40) * 2.5e-3)
    assert seq.gt_poses[3, 0, 3] == pytest.approx(4.5)


def test_kitti_root_sequence_and_part_of_a_recording(tmp_path):
    seq_dir = tmp_path / "sequences" / "05"
    for k in range(8):
        write_bin(seq_dir / "velodyne" / f"{k:06d}.bin", _points(k))
    (seq_dir / "calib.txt").write_text("Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    (seq_dir / "poses.txt").write_text(format_kitti(_poses(8)))
    seq = open_dataset(tmp_path, sequence="05").select(first=1, jump=2, count=3)
    assert len(seq) == 3
    np.testing.assert_allclose(seq[2].points, _points(5))
    np.testing.assert_allclose(seq.gt_poses[:, 0, 3], [2.0, 6.0, 10.0])
    with pytest.raises(InputError, match="--first 9 is beyond its 8 scans"):
        open_dataset(seq_dir).select(first=9)


@pytest.mark.parametrize(
    "selection, message",
    [
        ({"first": 5000}, r"dataset 'sim:test': --first 5000 is beyond its 214 scans \(0\.\.213\)"),
        ({"first": 212}, r"dataset 'sim:test': 2 scans selected; a run needs at least 3"),
        ({"jump": 200}, r"dataset 'sim:test': 2 scans selected; a run needs at least 3"),
        ({"frames": 2}, r"dataset 'sim:test': 2 scans selected; a run needs at least 3"),
        ({"first": 213}, r"dataset 'sim:test': 1 scan selected; a run needs at least 3"),
    ],
)
def test_a_simulated_sequence_refuses_what_it_cannot_select_before_it_is_simulated(tmp_path, selection, message):
    with pytest.raises(InputError, match=f"^{message}$"):
        open_sequence("sim:test", cache_dir=tmp_path, source=SourceOptions(**selection))
    assert not any(tmp_path.iterdir())  # nothing was cast


@pytest.mark.parametrize(
    "kind, selection, given",
    [
        ("mulran", {}, "--loader applies"),
        ("auto", {"topic": "/points"}, "--topic applies"),
        ("helipr", {"sequence": "05"}, "--loader, --sequence apply"),
    ],
)
def test_a_simulated_sequence_refuses_options_of_recordings_before_it_is_simulated(tmp_path, kind, selection, given):
    with pytest.raises(
        InputError,
        match=f"^dataset 'sim:test': {given} to recordings; a sim: dataset is one simulated sequence in KITTI's layout",
    ):
        open_sequence("sim:test", kind, cache_dir=tmp_path, source=SourceOptions(**selection))
    assert not any(tmp_path.iterdir())


def test_apollo_and_newer_college_times_are_real(tmp_path):
    apollo = tmp_path / "apollo"
    for k in range(N):
        _pcd(apollo / "pcds" / f"{k + 1}.pcd", _points(k), np.zeros(40), "binary")
    (apollo / "poses").mkdir()
    (apollo / "poses" / "gt_poses.txt").write_text(
        "".join(f"{k} {1500000000.5 + 0.1 * k} {k} 0 0 0 0 0 1\n" for k in range(N))
    )
    assert detect_loader(apollo) == "apollo"
    assert open_dataset(apollo).times[1] == pytest.approx(1500000000.6)
    ncd = tmp_path / "ncd"
    for k in range(N):
        _pcd(
            ncd / "raw_format" / "ouster_scan" / f"cloud_1583836591_{k * 100_000_000:09d}.pcd",
            _points(k),
            np.zeros(40),
            "ascii",
        )
    (ncd / "ground_truth").mkdir()
    (ncd / "ground_truth" / "registered_poses.csv").write_text(
        "".join(f"1583836591,{k * 100_000_000},{k},0,0,0,0,0,1\n" for k in range(N))
    )
    assert detect_loader(ncd) == "ncd"
    assert open_dataset(ncd).times[2] == pytest.approx(1583836591.2)


def _cloud_msg(typestore, k: int, stamp_ns: int):
    pts = _points(k)
    fields_t = typestore.types["sensor_msgs/msg/PointField"]
    rows = np.zeros(len(pts), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("t", "<u4")])
    rows["x"], rows["y"], rows["z"], rows["t"] = pts[:, 0], pts[:, 1], pts[:, 2], np.arange(len(pts)) * 1000
    fields = [fields_t(name=n, offset=4 * i, datatype=7 if n != "t" else 6, count=1) for i, n in enumerate("xyzt")]
    header_t = typestore.types["std_msgs/msg/Header"]
    ros1 = {"seq": k} if "seq" in header_t.__dataclass_fields__ else {}
    header = header_t(
        **ros1,
        stamp=typestore.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
        frame_id="os_sensor",
    )
    return typestore.types["sensor_msgs/msg/PointCloud2"](
        header=header,
        height=1,
        width=len(pts),
        fields=fields,
        is_bigendian=False,
        point_step=16,
        row_step=16 * len(pts),
        data=np.frombuffer(rows.tobytes(), np.uint8),
        is_dense=True,
    )


def _write_bag(path: Path, kind: str) -> None:
    """A bag with a PointCloud2 topic /points (N scans at 10 Hz) and a second one /other (1 scan)."""
    from rosbags.typesys import Stores, get_typestore

    msgtype = "sensor_msgs/msg/PointCloud2"
    stamps = [1_700_000_000_000_000_000 + k * 100_000_000 for k in range(N)]
    if kind == "ros1":
        from rosbags.rosbag1 import Writer

        store = get_typestore(Stores.ROS1_NOETIC)
        with Writer(path) as writer:
            conns = {t: writer.add_connection(t, msgtype, typestore=store) for t in ("/points", "/other")}
            for k, s in enumerate(stamps):
                writer.write(conns["/points"], s, store.serialize_ros1(_cloud_msg(store, k, s), msgtype))
            writer.write(conns["/other"], stamps[0], store.serialize_ros1(_cloud_msg(store, 9, stamps[0]), msgtype))
        return
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = get_typestore(Stores.ROS2_HUMBLE)
    plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {t: writer.add_connection(t, msgtype, typestore=store) for t in ("/points", "/other")}
        for k, s in enumerate(stamps):
            writer.write(conns["/points"], s, store.serialize_cdr(_cloud_msg(store, k, s), msgtype))
        writer.write(conns["/other"], stamps[0], store.serialize_cdr(_cloud_msg(store, 9, stamps[0]), msgtype))


def test_a_damaged_first_bag_message_stops_only_a_run_that_reads_it(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store, msgtype, bag = get_typestore(Stores.ROS1_NOETIC), "sensor_msgs/msg/PointCloud2", tmp_path / "run.bag"
    with Writer(bag) as writer:
        conn = writer.add_connection("/points", msgtype, typestore=store)
        for k in range(N):
            msg = _cloud_msg(store, k, 1_700_000_000_000_000_000 + k * 100_000_000)
            if k == 0:  # its first field renamed: no x
                msg.fields[0] = store.types["sensor_msgs/msg/PointField"](name="a", offset=0, datatype=7, count=1)
            writer.write(conn, 1_700_000_000_000_000_000 + k * 100_000_000, store.serialize_ros1(msg, msgtype))
    seq = open_dataset(bag)
    assert len(seq) == N and seq.select(first=1).point_times
    with pytest.raises(InputError, match=r"run.bag /points message 0: PointCloud2 has fields .*needs x, y and z"):
        seq.select(first=0)


@pytest.mark.parametrize("kind", ["ros1", "ros2", "mcap"])
def test_bags_by_topic(tmp_path, kind):
    bag = tmp_path / ("run.bag" if kind == "ros1" else "run")
    _write_bag(bag, kind)
    assert detect_loader(bag) == "rosbag"
    with pytest.raises(InputError, match="several PointCloud2 topics \\(/other, /points\\); name one with --topic"):
        open_dataset(bag)
    with pytest.raises(InputError, match="--topic /nope is not a PointCloud2 topic.*/other, /points"):
        open_dataset(bag, topic="/nope")
    seq = open_dataset(bag, topic="/points")
    assert len(seq) == N and seq.gt_poses is None
    np.testing.assert_allclose(seq.times - seq.times[0], 0.1 * np.arange(N), atol=1e-6)
    np.testing.assert_allclose(seq[2].points, _points(2), atol=1e-6)
    np.testing.assert_allclose(seq[2].timestamps, np.arange(40) * 1e-6)
    assert seq.point_times
    part = seq.select(first=1, jump=2)
    np.testing.assert_allclose(part[1].points, _points(3), atol=1e-6)
    from msa_slam.io.cache import sequence_identity

    assert sequence_identity(part) != sequence_identity(seq)  # a part is cached apart from the whole
    if kind != "ros1":
        files = sorted((bag).glob("*.mcap" if kind == "mcap" else "*.db3"))
        assert len(open_dataset(files[0], topic="/points")) == N  # the storage file itself
        alone = tmp_path / "alone" / files[0].name  # copied out of its folder, without metadata.yaml
        alone.parent.mkdir()
        alone.write_bytes(files[0].read_bytes())
        with pytest.raises(InputError, match=f"{alone}: a ROS2 bag file is read with its folder's metadata.yaml"):
            open_dataset(alone, topic="/points")


def test_open_sequence_options_and_oracle_needs_ground_truth(tmp_path):
    folder = tmp_path / "scans"
    for k in range(N):
        write_bin(folder / f"{k}.bin", _points(k))
    with pytest.raises(InputError, match="no ground-truth poses, which the oracle mode needs.*--mode realistic"):
        open_sequence(str(folder), mode="oracle")
    seq = open_sequence(str(folder), source=SourceOptions(first=1), mode="realistic")
    assert len(seq) == N - 1 and seq.gt_poses is None
    (tmp_path / "gt.txt").write_text(format_kitti(_poses()))
    seq = open_sequence(str(folder), source=SourceOptions(gt=str(tmp_path / "gt.txt"), frames=3), mode="oracle")
    np.testing.assert_allclose(seq.gt_poses, _poses()[:3])


def test_loader_names_match_the_cli_help():
    from msa_slam.cli.options import LOADER_HELP, LOADER_NAMES

    assert set(LOADER_NAMES) == set(LOADERS)
    assert all(name in LOADER_HELP for name in LOADERS)
    with pytest.raises(InputError, match="unknown dataset loader 'velodyne'; choose one of auto, kitti"):
        open_dataset(".", kind="velodyne")


@pytest.mark.parametrize("command", ["run", "online", "compare"])
def test_gt_format_option_reaches_the_pose_reader(tmp_path, command):
    from typer.testing import CliRunner

    from msa_slam.cli import app

    folder = tmp_path / "scans"
    for k in range(N):
        write_bin(folder / f"{k}.bin", _points(k))
    tum = tmp_path / "gt.txt"
    tum.write_text("".join(f"{k * 0.1:.1f} {2.0 * k} 0 0 0 0 0 1\n" for k in range(N)))
    args = [
        command,
        "--dataset",
        str(folder),
        "--gt",
        str(tum),
        "--mode",
        "realistic",
        "--out",
        str(tmp_path / "out"),
        "--cache-dir",
        str(tmp_path / "cache"),
        "--quiet",
    ]
    result = CliRunner().invoke(app, [*args, "--gt-format", "kitti"])
    assert result.exit_code != 0
    assert "gt.txt:1: 8 values, expected 12 (kitti format)" in str(result.output) + str(result.exception)
    result = CliRunner().invoke(app, [*args, "--gt-format", "g2o"])
    assert result.exit_code != 0 and "gt_format" in str(result.output) + str(result.exception)


TUM_HEADER = "# time tx ty tz qx qy qz qw\n"  # line 1; a blank line 3 follows pose 1, so pose k > 1 is on line k + 2


def _tum_file(path: Path, rows: list[str]) -> Path:
    """A TUM file whose line numbers differ from its pose numbers (a comment and a blank line)."""
    path.write_text(TUM_HEADER + rows[0] + "\n\n" + "".join(row + "\n" for row in rows[1:]))
    return path


def _tum_rows(n: int = N) -> list[str]:
    return [f"{0.1 * k:.1f} {2.0 * k} 0 0 0 0 0 1" for k in range(n)]


@pytest.mark.parametrize(
    ("time", "problem"),
    [
        ("0.1", "time 0.1 repeats the previous one (0.1 on line 4) on line 5; times must increase strictly"),
        ("0.05", "time 0.05 is before the previous one (0.1 on line 4) on line 5; times must increase strictly"),
        ("nan", "time nan is not a finite number on line 5"),
        ("inf", "time inf is not a finite number on line 5"),
    ],
)
def test_tum_times_are_checked_by_the_reader_naming_the_line(tmp_path, time, problem):
    from msa_slam.io.poses import read_poses

    rows = _tum_rows()
    rows[2] = " ".join([time, *rows[2].split()[1:]])
    path = _tum_file(tmp_path / "poses.txt", rows)
    with pytest.raises(InputError, match=re.escape(f"{path}: pose 3: {problem}")):
        read_poses(path)
    with pytest.raises(InputError, match=re.escape(f"{path}: pose 3: {problem}")):
        read_poses(path, "tum")
    for k in range(N):  # the sequence loader gets the reader's message (it no longer checks the times itself)
        write_bin(tmp_path / "scans" / f"{k}.bin", _points(k))
    with pytest.raises(InputError, match=re.escape(f"{path}: pose 3: {problem}")):
        open_dataset(tmp_path / "scans", poses=path)


@pytest.mark.parametrize(
    ("quaternion", "norm"),
    [
        ("0.7 0 0 0", "0.7"),  # corrupt, or the columns in another order
        ("0 0 0 0", "0"),
        ("0 0 nan 1", "nan"),
        ("0 0 inf 1", "inf"),
    ],
)
def test_tum_quaternion_far_from_unit_norm_is_refused_naming_the_line(tmp_path, quaternion, norm):
    from msa_slam.io.poses import read_poses

    rows = _tum_rows()
    rows[3] = " ".join([*rows[3].split()[:4], quaternion])
    path = _tum_file(tmp_path / "poses.txt", rows)
    with pytest.raises(InputError) as error:
        read_poses(path)
    message = str(error.value)
    assert message.startswith(f"{path}:6: quaternion (qx qy qz qw) ")
    assert f"has norm {norm}, not 1 (allowed deviation 0.01)" in message
    assert message.endswith("TUM columns are time tx ty tz qx qy qz qw")


def test_tum_quaternion_within_tolerance_is_normalised(tmp_path):
    """Writers that print few decimals are accepted; just past QUATERNION_TOLERANCE is refused."""
    from scipy.spatial.transform import Rotation

    from msa_slam.io.poses import QUATERNION_TOLERANCE, read_poses

    quat = Rotation.from_euler("z", 0.3).as_quat()
    rows = _tum_rows()
    rows[1] = " ".join([*rows[1].split()[:4], *(f"{q:.3f}" for q in quat)])
    rows[2] = " ".join([*rows[2].split()[:4], *(f"{q:.9f}" for q in quat * (1 + 0.9 * QUATERNION_TOLERANCE))])
    poses, times = read_poses(_tum_file(tmp_path / "ok.txt", rows))
    for k in (1, 2):
        np.testing.assert_allclose(poses[k, :3, :3], Rotation.from_euler("z", 0.3).as_matrix(), atol=2e-3)
    np.testing.assert_allclose(times, 0.1 * np.arange(N))
    rows[2] = " ".join([*rows[2].split()[:4], *(f"{q:.9f}" for q in quat * (1 + 1.1 * QUATERNION_TOLERANCE))])
    with pytest.raises(InputError, match=re.escape("bad.txt:5: quaternion (qx qy qz qw) ")):
        read_poses(_tum_file(tmp_path / "bad.txt", rows))


def test_sample_command_refuses_a_bad_tum_quaternion(tmp_path):
    from typer.testing import CliRunner

    from msa_slam.cli import app

    rows = _tum_rows()
    rows[1] = " ".join([*rows[1].split()[:4], "1 0 0 0.7"])  # norm 1.22: e.g. qw written twice
    path = _tum_file(tmp_path / "poses.txt", rows)
    np.save(tmp_path / "desc.npy", np.zeros((N, 8)))
    result = CliRunner().invoke(
        app,
        [
            "sample",
            "--poses",
            str(path),
            "--descriptors",
            str(tmp_path / "desc.npy"),
            "--out",
            str(tmp_path / "out"),
            "--quiet",
        ],
    )
    assert isinstance(result.exception, InputError), result.output
    assert str(result.exception).startswith(f"{path}:4: quaternion (qx qy qz qw) [1.0, 0.0, 0.0, 0.7] has norm 1.22066")
    assert not (tmp_path / "out").exists()


def test_ascii_pcd_with_a_bad_token_names_its_line(tmp_path):
    _pcd(tmp_path / "s.pcd", _points(0, 5), np.zeros(5), "ascii")
    lines = (tmp_path / "s.pcd").read_text().splitlines()
    lines[13] = "1.0 abc 3.0 0"  # header lines 1-11, points from line 12: the third point
    (tmp_path / "s.pcd").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"s.pcd:14: 'abc' is not a number \(PCD DATA ascii: 4 numbers a point\)"):
        read_timed_pcd(tmp_path / "s.pcd")
    lines[13] = "1.0 2.0 3.0"
    (tmp_path / "s.pcd").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"s.pcd:14: 3 values; its fields need 4 a point"):
        read_timed_pcd(tmp_path / "s.pcd")


def test_apollo_pose_file_with_a_bad_token_names_its_line(tmp_path):
    apollo = tmp_path / "apollo"
    for k in range(N):
        _pcd(apollo / "pcds" / f"{k + 1}.pcd", _points(k), np.zeros(40), "binary")
    (apollo / "poses").mkdir()
    lines = [f"{k} {1500000000.5 + 0.1 * k} {k} 0 0 0 0 0 1" for k in range(N)]
    lines[2] = lines[2].replace(" 0 0 0 0 1", " oops 0 0 0 1")
    (apollo / "poses" / "gt_poses.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"gt_poses.txt:3: not a number .*'oops'"):
        open_dataset(apollo)
    lines[2] = f"2 {1500000000.5 + 0.2} 2 0 0 0 0 1"
    (apollo / "poses" / "gt_poses.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"gt_poses.txt:3: 8 values; Apollo's gt_poses.txt has 9 a line \(index"):
        open_dataset(apollo)


@pytest.mark.parametrize("shift, first_bad", [(3600 * 10**9, 0), (None, 2)])
def test_mulran_pose_file_not_covering_the_scans_is_refused(tmp_path, shift, first_bad):
    """Poses an hour after the scans, or 2 poses for 4 scans, gave a constant ground truth without a word."""
    _mulran(tmp_path / "M")
    rows = np.loadtxt(tmp_path / "M" / "global_pose.csv", delimiter=",", ndmin=2)
    rows = rows[:2] if shift is None else rows + np.r_[shift, np.zeros(12)]
    np.savetxt(tmp_path / "M" / "global_pose.csv", rows, delimiter=",", fmt="%.17g")
    with pytest.raises(InputError, match=rf"M/global_pose.csv: no pose within 0.05 s of scan {first_bad} "):
        open_dataset(tmp_path / "M")


def _tum(path: Path, times: np.ndarray, poses: np.ndarray) -> Path:
    rows = np.column_stack([times, poses[:, :3, 3], np.tile([0, 0, 0, 1.0], (len(poses), 1))])
    path.write_text("".join(" ".join(f"{v:.9f}" for v in r) + "\n" for r in rows))
    return path


def _timed_kitti(root: Path, n: int = N) -> Path:
    """A KITTI layout with times.txt (0.1 s apart) and no poses."""
    for k in range(n):
        write_bin(root / "velodyne" / f"{k:06d}.bin", _points(k))
    (root / "times.txt").write_text("".join(f"{0.1 * k:.6f}\n" for k in range(n)))
    return root


def test_tum_ground_truth_with_one_pose_a_scan_is_matched_by_time(tmp_path):
    """A TUM file with as many poses as scans was taken line by line, whatever its times said."""
    seq = _timed_kitti(tmp_path / "k")
    jittered = _tum(tmp_path / "same.tum", 0.1 * np.arange(N) + 0.01, _poses())
    np.testing.assert_allclose(open_dataset(seq, poses=jittered).gt_poses, _poses())
    shifted = _tum(tmp_path / "shifted.tum", 0.1 * np.arange(1, N + 1), _poses())  # one frame late
    with pytest.raises(
        InputError,
        match=r"shifted.tum: no pose within 0.05 s of scan 0 \(time 0.000000 s; nearest "
        r"pose at 0.100000 s\); the pose times must be the scans' clock",
    ):
        open_dataset(seq, poses=shifted)
    other_clock = _tum(tmp_path / "clock.tum", 1.7e9 + 0.1 * np.arange(N), _poses())
    with pytest.raises(InputError, match=r"clock.tum: no pose within 0.05 s of scan 0 "):
        open_dataset(seq, poses=other_clock)


def test_tum_ground_truth_gives_untimed_scans_its_times(tmp_path):
    """Scans without timestamps take a TUM file's one pose a scan, in order, and its times (as a folder does)."""
    seq = tmp_path / "k"
    for k in range(N):
        write_bin(seq / "velodyne" / f"{k:06d}.bin", _points(k))
    gt = _tum(tmp_path / "gt.tum", 50.0 + 0.1 * np.arange(N), _poses())
    opened = open_dataset(seq, poses=gt)
    np.testing.assert_allclose(opened.gt_poses, _poses())
    np.testing.assert_allclose(opened.times, 50.0 + 0.1 * np.arange(N))
    assert opened.times_known
    short = _tum(tmp_path / "short.tum", 50.0 + 0.1 * np.arange(N - 1), _poses(N - 1))
    with pytest.raises(
        InputError,
        match=r"short.tum: 3 poses but .*k has 4 scans, which have no timestamps to "
        r"match the TUM times to; give one pose a scan",
    ):
        open_dataset(seq, poses=short)
