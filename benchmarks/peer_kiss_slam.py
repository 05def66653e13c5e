"""Run the peer, KISS-SLAM (PRBonn, pip `kiss-slam`), or KISS-ICP alone with KISS-SLAM's odometry settings,
on a KITTI-layout sequence folder written by `msa-slam simulate`; bench_peer.py calls it with the Python
that has kiss-slam installed (a separate venv: kiss-slam pins numpy and pydantic older than msa-slam's).

It imports numpy and the peer only (no msa_slam). Scans are velodyne/NNNNNN.bin (x, y, z, intensity) and,
when the folder has them, velodyne_times/NNNNNN.npy (per-point seconds from the sweep start), given to the peer
as its per-point timestamps so that it deskews as it does with any loader that has them (--no-times: none, so
no deskew, as the kiss_slam_pipeline CLI runs on .bin scans). The CLI cannot give them: its KITTI and generic
loaders read .bin scans without per-point times. Scans of a simulated KITTI HDL-64 (sim.json records a sensor
elevation error) get kiss-icp's own KITTI vertical-angle correction, as its KITTI loader applies it to real KITTI
and as msa-slam's KITTI-layout reader does, so both systems see the same points.

The sequence is processed as kiss_slam.pipeline.SlamPipeline does (process_scan per frame, then the last
local map closed and the fine-grained optimisation over every frame); KISS-ICP alone registers every frame
with KISS-SLAM's odometry configuration. Written to OUT (.npz): `poses` (frames, 4, 4), world-from-LiDAR in
the first scan's frame, `seconds` (processing time, scans' reading excluded), `closures` (KISS-SLAM: loop
closures found between local maps; -1 for KISS-ICP), `threads`.

    peer-python benchmarks/peer_kiss_slam.py {slam,icp} SEQUENCE_DIR OUT.npz [--end N] [--threads 1] [--no-times]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def needs_kitti_correction(folder: Path) -> bool:
    """Whether the simulator recorded a sensor elevation error for this sequence (its HDL-64 as KITTI's)."""
    try:
        sensor = json.loads((folder / "sim.json").read_text()).get("sensor") or {}
    except (OSError, ValueError):
        return False
    return bool(sensor.get("elevation_bias_deg"))


def frames(folder: Path, end: int | None, times: bool = True):
    """(points (P, 3) float64, per-point times (P,) or an empty array: none stored, or `times` False) of each
    scan, in order (vertical-angle corrected as kiss-icp's KITTI loader does, where needs_kitti_correction)."""
    from kiss_icp.pybind import kiss_icp_pybind

    correct = needs_kitti_correction(folder)
    scans = sorted((folder / "velodyne").glob("*.bin"))[:end]
    for scan in scans:
        points = np.fromfile(scan, dtype=np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
        if correct:
            points = np.asarray(kiss_icp_pybind._correct_kitti_scan(kiss_icp_pybind._Vector3dVector(points)))
        stamps = folder / "velodyne_times" / f"{scan.stem}.npy"
        yield points, (np.load(stamps).astype(np.float64) if times and stamps.is_file() else np.zeros(0))


def run(method: str, folder: Path, end: int | None, threads: int, times: bool = True) -> dict[str, np.ndarray]:
    from kiss_slam.config import KissSLAMConfig
    from kiss_slam.slam import KissSLAM

    config = KissSLAMConfig.model_construct()  # the defaults, no environment variables (kiss_slam_*)
    config.odometry.registration.max_num_threads = threads
    if config.odometry.mapping.voxel_size is None:  # as kiss_slam.config.load_config
        config.odometry.mapping.voxel_size = float(config.odometry.preprocessing.max_range / 100.0)
    seconds, poses = 0.0, []
    if method == "slam":
        slam = KissSLAM(config)
        for points, stamps in frames(folder, end, times):
            start = time.perf_counter()
            slam.process_scan(points, stamps)
            seconds += time.perf_counter() - start
        start = time.perf_counter()
        slam.generate_new_node()
        slam.local_map_graph.erase_last_local_map()
        poses, _ = slam.fine_grained_optimization()
        seconds += time.perf_counter() - start
        closures = len(slam.closures)
    else:
        from kiss_icp.kiss_icp import KissICP

        odometry = KissICP(config.kiss_icp_config())
        for points, stamps in frames(folder, end, times):
            start = time.perf_counter()
            odometry.register_frame(points, stamps)
            poses.append(np.array(odometry.last_pose))
            seconds += time.perf_counter() - start
        closures = -1
    return {
        "poses": np.asarray(poses, dtype=np.float64),
        "seconds": np.float64(seconds),
        "closures": np.int64(closures),
        "threads": np.int64(threads),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("method", choices=("slam", "icp"))
    parser.add_argument("sequence", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--end", type=int, default=None, help="first N scans only")
    parser.add_argument("--threads", type=int, default=1, help="KISS-ICP threads (0: all cores)")
    parser.add_argument(
        "--no-times",
        action="store_true",
        help="give no per-point times (no deskew), as the peer's CLI reads .bin scans",
    )
    args = parser.parse_args()
    np.savez(args.out, **run(args.method, args.sequence, args.end, args.threads, not args.no_times))


if __name__ == "__main__":
    main()
