"""Simulator speed: scans per second per sensor, world build time, the embedded defaults, and the whole
KITTI-00 trajectory (4541 frames) at HDL-64 resolution (target: at most 10 minutes on 2 cores).

Usage: python benchmarks/bench_sim.py [--full]   (--full simulates all 4541 KITTI-00 frames to a temp
dir instead of extrapolating from a sample of frames spread over the trajectory).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from msa_slam.sim import DEFAULT_CONFIGS, SENSORS, build_world, load_trajectory, make_config, prepare
from msa_slam.sim.sequence import simulate_sequence

SAMPLE = 40  # frames spread over the trajectory for per-scan timings
REPEATS = 3


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def world_build(traj_name: str) -> tuple[float, int]:
    poses = load_trajectory(traj_name).poses
    times = [_timed(lambda: build_world(poses, "city", 0)) for _ in range(REPEATS)]
    return statistics.median(times), build_world(poses, "city", 0).triangles


def per_scan(config, write_dir: Path | None = None) -> tuple[float, float]:
    """Median seconds per scan (cast + noise, plus writing the .bin when write_dir) and mean points."""
    sim = prepare(config)
    picks = np.linspace(0, len(sim) - 1, min(SAMPLE, len(sim))).astype(int)
    sim.scan(int(picks[0]))  # warm-up: Embree builds its BVH on the first cast
    times, points = [], []
    for k in picks:
        t = time.perf_counter()
        pts, point_times = sim.scan(int(k))
        if write_dir is not None:
            pts.tofile(write_dir / f"{k:06d}.bin")
            if point_times is not None:
                np.save(write_dir / f"{k:06d}.npy", point_times.astype(np.float32))
        times.append(time.perf_counter() - t)
        points.append(len(pts))
    return statistics.median(times), float(np.mean(points))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="simulate all of KITTI-00 instead of extrapolating")
    args = parser.parse_args()

    build_s, tris = world_build("kitti-00")
    print(f"World build, whole KITTI-00 path (3.7 km): {build_s:.2f} s median of {REPEATS}, {tris} triangles\n")

    print(f"Scans per second on the KITTI-00 world (median over {SAMPLE} frames spread over the path)")
    print(f"{'sensor':<10}{'beams x azimuth':>16}{'points/scan':>13}{'ms/scan':>10}{'scans/s':>9}")
    rows = [(name, None) for name in SENSORS] + [
        ("hdl64", DEFAULT_CONFIGS["demo"].azimuth_steps),
        ("hdl64", DEFAULT_CONFIGS["test"].azimuth_steps),
    ]
    for name, az in rows:
        cfg = make_config(trajectory="kitti-00", sensor=name, azimuth_steps=az)
        sec, pts = per_scan(cfg)
        model = SENSORS[name]
        print(
            f"{name:<10}{f'{model.beams} x {az or model.azimuth_steps}':>16}{pts:>13.0f}{1000 * sec:>10.1f}"
            f"{1 / sec:>9.1f}"
        )

    print("\nWhole KITTI-00 (4541 frames), HDL-64 at its default 64 x 1800, written to disk")
    full_cfg = make_config(trajectory="kitti-00", sensor="hdl64")
    with tempfile.TemporaryDirectory() as tmp:
        if args.full:
            total = _timed(lambda: simulate_sequence(full_cfg, out=Path(tmp) / "seq", progress=True))
            print(f"  measured: {total:.0f} s ({total / 60:.1f} min) including the world build")
        else:
            sec, _ = per_scan(full_cfg, write_dir=Path(tmp))
            total = build_s + 4541 * sec
            print(
                f"  extrapolated from {SAMPLE} frames: {sec * 1000:.1f} ms/scan x 4541 + {build_s:.1f} s world"
                f" = {total:.0f} s ({total / 60:.1f} min; target <= 10 min)"
            )

    print("\nEmbedded defaults, generated from scratch (measured)")
    for kind, cfg in DEFAULT_CONFIGS.items():
        with tempfile.TemporaryDirectory() as tmp:
            sec = _timed(lambda: simulate_sequence(cfg, out=Path(tmp) / kind))
            n = len(list((Path(tmp) / kind / "velodyne").glob("*.bin")))
            size = sum(f.stat().st_size for f in (Path(tmp) / kind / "velodyne").iterdir()) / 1e6
        print(
            f"  {kind:<5} {cfg.trajectory} stride {cfg.stride}, {n} frames, 64 x {cfg.azimuth_steps}: "
            f"{sec:.1f} s, {size:.0f} MB"
        )


if __name__ == "__main__":
    main()
