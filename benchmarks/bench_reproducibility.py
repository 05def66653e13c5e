"""Where results part across CPUs: digests of each stage of the demo's data on this machine, to compare with
another machine's (docs/simulator.md, "Across CPUs", lists the digests seen so far).

The demo's comparison differs between CPUs (one loop more or less, other keyframes) while two runs on one
machine give identical bytes. This prints a digest of every stage that feeds the result, on the demo's sequence
(sim:demo: KITTI-06, HDL-64 at 720 azimuth steps, `kitti` realism): the world the simulator builds (mesh,
reflectance, materials), its scans in blocks of frames, their per-point times, the Scan Context descriptors and
the KISS-ICP odometry of the first frames. Run it on two machines: the first row whose digest differs is the
stage to look at. It also names what picks CPU-specific code: the CPU model, numpy's BLAS core and embree's ISA.

    python benchmarks/bench_reproducibility.py [--frames N] [--odometry-frames N] [--block N]
"""

from __future__ import annotations

import argparse
import hashlib
import time

import numpy as np
import threadpoolctl

from msa_slam.descriptors import make_descriptor
from msa_slam.io.provenance import cpu_model
from msa_slam.odometry import KissOdometry
from msa_slam.sim import DEFAULT_CONFIGS, prepare


def digest(*arrays: np.ndarray) -> str:
    """First 16 hex digits of the SHA-256 of the arrays' bytes (C order), in turn."""
    h = hashlib.sha256()
    for array in arrays:
        h.update(np.ascontiguousarray(array).tobytes())
    return h.hexdigest()[:16]


def cpu_line() -> str:
    """CPU model, family/model numbers and whether it has AVX-512 (what CPU-dispatched libraries look at)."""
    fields: dict[str, str] = {}
    with open("/proc/cpuinfo") as handle:
        for line in handle:
            if not line.strip():
                break
            key, _, value = line.partition(":")
            fields[key.strip()] = value.strip()
    flags = fields.get("flags", "").split()
    return (
        f"{cpu_model()}, family {fields.get('cpu family', '?')} model {fields.get('model', '?')}, "
        f"AVX-512 {'yes' if 'avx512f' in flags else 'no'}, AVX2 {'yes' if 'avx2' in flags else 'no'}"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=None, help="scans to cast (default: all 1101)")
    parser.add_argument("--odometry-frames", type=int, default=150, help="frames run through KISS-ICP (default 150)")
    parser.add_argument("--block", type=int, default=250, help="frames per scan-digest row (default 250)")
    args = parser.parse_args()
    for name in ("frames", "odometry_frames", "block"):
        value = getattr(args, name)
        if value is not None and value < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1, got {value}")
    blas = [
        f"{i['internal_api']} {i.get('architecture', '?')} {i['version']}"
        for i in threadpoolctl.threadpool_info()
        if i["user_api"] == "blas"
    ]
    print(f"CPU: {cpu_line()}; numpy BLAS: {', '.join(blas) or 'none found'}")
    started = time.perf_counter()
    sim = prepare(DEFAULT_CONFIGS["demo"])
    frames = len(sim) if args.frames is None else min(args.frames, len(sim))
    world = sim.world
    rows = [
        (
            "world mesh (vertices, faces)",
            f"{len(world.mesh.faces)} faces",
            digest(np.asarray(world.mesh.vertices), np.asarray(world.mesh.faces)),
        ),
        ("world reflectance, materials", f"{len(world.reflectance)} faces", digest(world.reflectance, world.material)),
    ]
    descriptor = make_descriptor("sc")
    scans, times, descriptors, odometry_scans = [], [], [], []
    every_scan = hashlib.sha256()  # = `cat velodyne/*.bin | sha256sum` of the demo's cached sequence
    for k in range(frames):
        points, point_times = sim.scan(k)
        every_scan.update(np.ascontiguousarray(points).tobytes())
        scans.append(points)
        times.append(np.zeros(0) if point_times is None else point_times)
        descriptors.append(descriptor.compute(points[:, :3], k))
        if k < args.odometry_frames:
            odometry_scans.append((points[:, :3], point_times))
        if len(scans) == args.block or k == frames - 1:
            first = k + 1 - len(scans)
            rows.append((f"scans {first}-{k}", f"{sum(len(s) for s in scans)} points", digest(*scans)))
            rows.append((f"per-point times {first}-{k}", "", digest(*times)))
            rows.append((f"Scan Context {first}-{k}", "", digest(np.stack(descriptors))))
            scans, times, descriptors = [], [], []
    rows.append((f"every scan 0-{frames - 1} in turn", "cat velodyne/*.bin", every_scan.hexdigest()[:16]))
    kiss = KissOdometry(deskew=True)  # as the pipeline runs the demo: its scans carry per-point times
    poses = np.stack(
        [kiss.register(points, stamps, float(sim.times[k])) for k, (points, stamps) in enumerate(odometry_scans)]
    )
    rows.append((f"KISS-ICP odometry 0-{len(poses) - 1}", f"end {poses[-1, :3, 3].round(3).tolist()} m", digest(poses)))
    print(f"\nDigests of the demo's stages (sim:demo, SHA-256 first 16 hex; {time.perf_counter() - started:.0f} s)")
    print(f"{'stage':34} {'size':32} digest")
    for stage, size, value in rows:
        print(f"{stage:34} {size:32} {value}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
