"""Live view of an online run in Rerun (the optional `viewer` extra, `pip install rerun-sdk`): the current
scan, the odometry and iSAM2-optimised trajectories, keyframes and accepted loops as they happen, on a
`frame` timeline; shown in a Rerun window or saved as a .rrd recording (`rerun run.rrd` replays it)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from msa_slam.errors import InputError

MAX_SCAN_POINTS = 30_000  # the scan is thinned to this many points: the view stays fluid at 10 Hz
ENTITIES = ("world/scan", "world/odometry", "world/optimised", "world/keyframes", "world/loops")


def check_viewer(save: str | os.PathLike | None = None) -> None:
    """Raise InputError, before any work, when rerun-sdk is missing or `save` names an existing file."""
    try:
        import rerun  # noqa: F401
    except ImportError:
        raise InputError(
            "--viewer / --viewer-save need the optional rerun-sdk package: "
            "pip install 'msa-slam[viewer]' (or pip install rerun-sdk)"
        ) from None
    if save is not None and os.path.lexists(save):
        raise InputError(
            f"--viewer-save {save}: the file exists; give a new name (msa-slam never replaces a file it did not write)"
        )


class LiveViewer:
    """Logs an online run to Rerun: `frame` after each frame, `finish` with the final result, then `close`.
    A Rerun window is spawned unless `save` names a new .rrd file to record to."""

    def __init__(self, save: str | os.PathLike | None = None) -> None:
        check_viewer(save)
        import rerun as rr

        self.rr = rr
        self.rec = rr.RecordingStream("msa-slam")
        if save is None:
            self.rec.spawn()
        else:
            self.rec.save(str(save))
        self._odometry: list[np.ndarray] = []

    def frame(self, backend: Any, index: int, points: np.ndarray, new_keyframes: list[int]) -> None:
        """Log frame `index` of a msa_slam.slam.SlamBackend: its scan at its odometry pose, the odometry so far
        and, when it finalised keyframes, the current iSAM2 estimate with keyframes and accepted loops."""
        rr = self.rr
        self.rec.set_time("frame", sequence=index)
        pose = backend.odometry[index]
        scan = np.asarray(points, dtype=np.float64)[:, :3][:: max(1, len(points) // MAX_SCAN_POINTS)]
        self.rec.log("world/scan", rr.Points3D(scan @ pose[:3, :3].T + pose[:3, 3], radii=0.03))
        self._odometry.append(pose[:3, 3].copy())
        self.rec.log("world/odometry", rr.LineStrips3D([np.array(self._odometry)], colors=[150, 150, 150]))
        if new_keyframes and len(backend.keyframes):
            self._graph(backend.keyframes, backend.graph.estimate(), backend.loops)

    def finish(self, result: Any) -> None:
        """Log the run's final optimised keyframe trajectory and loops (msa_slam.slam.RunResult)."""
        self.rec.set_time("frame", sequence=max(len(result) - 1, 0))
        self._graph(list(result.keyframes), result.optimised, result.loops)

    def _graph(self, keys: list[int], poses: np.ndarray, loops: list) -> None:
        rr = self.rr
        xyz = np.asarray(poses)[:, :3, 3]
        self.rec.log("world/optimised", rr.LineStrips3D([xyz], colors=[31, 119, 180]))
        self.rec.log("world/keyframes", rr.Points3D(xyz, radii=0.3, colors=[214, 39, 40]))
        row = {int(k): i for i, k in enumerate(keys)}
        segments = [
            xyz[[row[c.match], row[c.query]]] for c in loops if c.accepted and c.match in row and c.query in row
        ]
        self.rec.log("world/loops", rr.LineStrips3D(segments, colors=[255, 127, 14]))

    def close(self) -> None:
        """Flush the recording (a saved .rrd is complete after this)."""
        self.rec.flush()
        self.rec.disconnect()
