"""ROS bags through the `rosbags` package (the library kiss-icp's rosbag loader uses): ROS1 .bag files (one,
or a folder of split bags), ROS2 bag folders (sqlite3 or MCAP storage, metadata.yaml) and their .db3/.mcap
files. One sensor_msgs/PointCloud2 topic is one sequence; scans are read on demand by timestamp, so a bag
is read once to index it and never copied.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from msa_slam.datasets.frame import Frame
from msa_slam.datasets.pcd import TIME_FIELDS
from msa_slam.datasets.points import checked_points
from msa_slam.datasets.sequences import ScanSequence
from msa_slam.errors import InputError
from msa_slam.io.poses import check_times

BAG_SUFFIXES = (".bag", ".mcap", ".db3")
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"


def is_bag(path: Path) -> bool:
    """A bag file, a ROS2 bag folder (metadata.yaml) or a folder of ROS1 .bag files."""
    if path.is_file():
        return path.suffix.lower() in BAG_SUFFIXES
    return (path / "metadata.yaml").is_file() or any(path.glob("*.bag"))


def bag_files(path: Path) -> list[Path]:
    """What rosbags opens for `path`: the .bag files of a folder of split ROS1 bags, else `path` itself
    (a ROS2 bag is its folder; a lone .db3/.mcap file is read as the folder that holds it)."""
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        return sorted(path.glob("*.bag"))
    if path.is_file() and path.suffix.lower() in (".db3", ".mcap"):
        if not (path.parent / "metadata.yaml").is_file():  # rosbags reads a ROS2 bag through its metadata
            raise InputError(
                f"{path}: a ROS2 bag file is read with its folder's metadata.yaml, which "
                f"{path.parent} lacks; give the bag's folder as recorded (ros2 bag reindex "
                "rebuilds a lost metadata.yaml)"
            )
        return [path.parent]
    return [path]


def _reader(paths: list[Path]):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    return AnyReader(paths, default_typestore=get_typestore(Stores.ROS2_HUMBLE))


def cloud_arrays(msg, where: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (P, 3) of a PointCloud2 message and each point's seconds since its earliest one (None without a
    time field; integer time fields count nanoseconds), NaN points dropped from both."""
    from kiss_icp.tools.point_cloud2 import read_points

    names = [f.name for f in msg.fields]
    if not {"x", "y", "z"} <= set(names):
        raise InputError(f"{where}: PointCloud2 has fields {names}, needs x, y and z")
    table = read_points(msg)
    xyz = np.stack([table[a].astype(np.float64) for a in "xyz"], axis=1).reshape(-1, 3)
    keep = ~np.isnan(xyz).any(axis=1)
    points = checked_points(xyz, Path(where))
    name = next((f for f in TIME_FIELDS if f in names), None)
    if name is None:
        return points, None
    raw = table[name].reshape(-1)[keep]
    times = raw.astype(np.float64) * (1e-9 if raw.dtype.kind in "iu" else 1.0)
    return points, times - times.min()


class BagSequence(ScanSequence):
    """The PointCloud2 messages of one topic of a bag, in recording order, read by timestamp when asked."""

    forkable = False  # the bag stays open: a forked reader would share its file handles (offsets) or database

    def __init__(self, path: str | os.PathLike, topic: str | None = None) -> None:
        self.path = Path(path)
        self.name = self.path.stem if self.path.is_file() else self.path.name
        self.scan_files = bag_files(self.path)
        if not self.scan_files:
            raise InputError(f"{self.path}: no .bag files in this folder")
        try:
            self._bag = _reader(self.scan_files)
            self._bag.open()
        except Exception as exc:  # rosbags raises its own error types for every malformed bag
            raise InputError(f"{self.path}: cannot open as a ROS bag ({exc})") from None
        self.topic = self._pick_topic(topic)
        self._connections = [c for c in self._bag.connections if c.topic == self.topic]
        self._log_times, header_times = [], []
        for connection, stamp, raw in self._bag.messages(connections=self._connections):
            msg = self._bag.deserialize(raw, connection.msgtype)
            self._log_times.append(int(stamp))
            header_times.append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
        if not self._log_times:
            raise InputError(f"{self.path}: topic {self.topic} has no messages")
        header = np.asarray(header_times)
        use_header = len(header) < 2 or bool(np.all(np.diff(header) > 0))
        times = header if use_header else np.asarray(self._log_times, dtype=np.float64) * 1e-9
        self.times = check_times(times, lambda i: f"{self.path}: {self.topic} message {i}")
        self._rows = np.arange(len(self.times))
        self.gt_poses = None
        self.selection = {"topic": self.topic, "rows": self._rows.tolist()}  # no message read yet: select reads
        # the first one a run reads (a damaged message 0 stops only a run that reads it)

    def _pick_topic(self, topic: str | None) -> str:
        clouds = sorted(t for t, info in self._bag.topics.items() if info.msgtype == POINTCLOUD2)
        listed = ", ".join(clouds) or "none"
        if topic is not None and topic not in clouds:
            raise InputError(
                f"{self.path}: --topic {topic} is not a PointCloud2 topic of this bag; its PointCloud2 topics: {listed}"
            )
        if topic is None and len(clouds) != 1:
            what = "has no PointCloud2 topic" if not clouds else f"has several PointCloud2 topics ({listed})"
            raise InputError(f"{self.path}: {what}; name one with --topic")
        return topic or clouds[0]

    def __len__(self) -> int:
        return len(self._rows)

    def __getitem__(self, index: int) -> Frame:
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} scans")
        index %= len(self)
        row = int(self._rows[index])
        stamp = self._log_times[row]
        rank = row - self._log_times.index(stamp)  # messages logged at the same nanosecond, in order
        messages = self._bag.messages(connections=self._connections, start=stamp, stop=stamp + 1)
        for k, (connection, _, raw) in enumerate(messages):
            if k == rank:
                msg = self._bag.deserialize(raw, connection.msgtype)
                break
        else:
            raise InputError(f"{self.path}: {self.topic} message {row} is no longer in the bag")
        points, stamps = cloud_arrays(msg, f"{self.path} {self.topic} message {row}")
        gt = None if self.gt_poses is None else self.gt_poses[index]
        return Frame(index, float(self.times[index]), points, gt, stamps)

    def _take(self, rows: np.ndarray) -> None:
        self.gt_poses = None if self.gt_poses is None else self.gt_poses[rows]
        self.times = self.times[rows]
        self._rows = self._rows[rows]
        self.selection = {"topic": self.topic, "rows": self._rows.tolist()}

    def close(self) -> None:
        self._bag.close()
