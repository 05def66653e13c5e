"""Online pipeline throughput per sampler on the HDL-64 simulated KITTI-05 trajectory.

Scans are simulated once into memory (by default the demo's setting: every 3rd frame of the whole
trajectory, 921 scans with its three revisit stretches, 720 azimuth steps) so the timings cover only the
pipeline. Odometry is ground truth with seeded noise: KISS-ICP is timed apart on the first scans, since
it alone takes ~0.2 s a scan here. Reported per sampler (median over --repeats runs): back-end frames per
second (everything after odometry: descriptor, sampler, keyframe store, loop detection, verification,
iSAM2), real-time factor at 10 Hz, milliseconds per frame of each stage, and per-frame latency p50/p99.
Target: >= 20 back-end frames per second with MSA + Scan Context.

    .venv/bin/python benchmarks/bench_online.py [--frames N] [--stride 3] [--repeats 3] [--samplers msa,all]

`--scale` instead runs the long online runs once each, with MSA + Scan Context, keyframe clouds on disk and
ground-truth + noise odometry: the whole KITTI-00 trajectory (4541 scans, 3.7 km) and the city tour driven
10 times forth and back (25,900 scans, 22 km, every street revisited 9 times), scans simulated as the run
goes (360 azimuth steps, to keep the ray casting short); it reports bytes per keyframe, accounted memory,
RSS at 10 % and at the end of the run, and peak RSS.

`--memory [--laps 3]` checks that the accounted bytes explain the RSS: after a 300-frame warm-up in the same
process (compiled kernels, lazily loaded libraries: one-time costs, not the run's), the city tour driven
--laps times (MSA + Scan Context, clouds on disk, ground truth + noise) prints a table of the accounted bytes
by part, the run's RSS growth and their ratio (target <= 1.5), over the whole run and from the end of the
first lap on. Measured with this command (3 laps: 7,833 frames, ~3,380 keyframes; 10 laps: 26,110 frames,
11,190 keyframes, 9,957 loops, 3,186 s; busy machine):

| | descriptors | graph | records | map | accounted in RAM | RSS growth | ratio | after lap 1 (RSS / accounted) |
|---|---|---|---|---|---|---|---|---|
| 3 laps, before (973d9fd) | 31.9 MiB | 10.1 MiB | - | - | 42.0 MiB | 139.6 MiB | 3.32 | 93.2 / 29.2 MiB = 3.19 |
| 3 laps, after | 31.9 MiB | 50.8 MiB | 4.7 MiB | 9.4 MiB | 96.8 MiB | 84.6 MiB | 0.87 | 84.1 / 66.2 MiB = 1.27 |
| 10 laps (6762909) | 105.6 MiB | 353.9 MiB | 21.5 MiB | 13.2 MiB | 494.1 MiB | 624.7 MiB | 1.26 | 600.4 / 458.3 MiB = 1.31 |

Before, GTSAM's heap was estimated at about a fifth of what it holds and freed heap pages stayed resident (on
10 laps: RSS 436 -> 1064 MiB against 119 MiB accounted). The 3-lap "after" growth started from an
unsettled reading, which could still hold the warm-up's freed heap and so lowered the growth; since 6762909
both ends are read after garbage collection and malloc_trim (evaluation.resources.settle_heap). Over 10 laps
the graph is most of it: iSAM2's Bayes tree with ~10,000 loop factors.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from msa_slam.datasets import Frame
from msa_slam.evaluation import fmt
from msa_slam.odometry import KissOdometry
from msa_slam.pipeline import LiveFrontEnd, run
from msa_slam.pipeline.config import make_online_config
from msa_slam.pipeline.live import STEPS
from msa_slam.sources import open_source
from msa_slam.types import FrameSource

SAMPLERS = {
    "all": ("all", {}),
    "constant-3m": ("constant", {"distance": 3.0}),
    "entropy": ("entropy", {}),
    "spaciousness": ("spaciousness", {}),
    "msa": ("msa", {}),
    "msa-fast": ("msa", {"mode": "fast"}),
}


def in_memory(spec: str, frames: int | None) -> FrameSource:
    source = open_source(spec)
    scans = []
    t0 = time.perf_counter()
    for i, frame in enumerate(source.frames()):
        if frames is not None and i >= frames:
            break
        scans.append(frame)
    print(
        f"simulated {len(scans)} scans of {spec} in {time.perf_counter() - t0:.0f} s "
        f"({np.mean([len(f.points) for f in scans]):.0f} points each)"
    )
    gt = source.gt_poses[: len(scans)]
    return FrameSource(source.name, gt, lambda: (Frame(f.index, f.time, f.points, f.gt_pose) for f in scans))


def kiss_rate(source: FrameSource, n: int) -> float:
    odometry = KissOdometry()
    times = []
    for i, frame in enumerate(source.frames()):
        if i >= n:
            break
        t0 = time.perf_counter()
        odometry.register(frame.points)
        times.append(time.perf_counter() - t0)
    return float(np.median(times[1:]))


SCALE_RUNS = ("live:kitti-00,sensor=hdl64,azimuth_steps=360", "live:city-tour,sensor=hdl64,azimuth_steps=360,laps=10")


def scale(quiet: bool) -> None:
    import tempfile

    head = [
        "run",
        "frames",
        "km",
        "keyframes",
        "loops",
        "false",
        "ATE odom -> iSAM2 [m]",
        "F1-max",
        "bytes/keyframe (RAM + disk)",
        "accounted RAM MiB",
        "clouds on disk MiB",
        "RSS @10% MiB",
        "RSS end MiB",
        "peak RSS MiB",
        "back-end fps",
        "p99 ms",
        "wall s",
    ]
    rows = []
    for spec in SCALE_RUNS:
        with tempfile.TemporaryDirectory(prefix="msa-scale-") as store:
            cfg = make_online_config(
                dataset=spec, odometry="gt-noise", sampler="msa", cloud_store="disk", store_dir=store
            )
            t0 = time.perf_counter()
            r = run(cfg, quiet=quiet)
            wall = time.perf_counter() - t0
        m, mem = r.metrics, r.memory
        kt, th = m.keyframe_trajectory, m.throughput
        km = float(np.linalg.norm(np.diff(r.gt_poses[:, :3, 3], axis=0), axis=1).sum()) / 1e3
        ram = mem["descriptor_bytes"][-1] + mem["graph_bytes"][-1] + mem["cloud_bytes"][-1]
        mib = lambda b: f"{b / 2**20:.0f}"  # noqa: E731
        rows.append(
            [
                r.name,
                m.run.frames,
                f"{km:.1f}",
                m.run.keyframes,
                m.loops.verified,
                fmt(m.loops.false_loops, "d"),
                f"{fmt(kt.before.ate_translation_m, '.2f')} -> {fmt(kt.after.ate_translation_m, '.2f')}",
                fmt(m.place_recognition.f1_max),
                f"{m.memory.bytes_per_keyframe(m.run.keyframes):.0f}",
                mib(ram),
                mib(m.memory.accounted.clouds_on_disk),
                mib(mem["rss_bytes"][len(mem["rss_bytes"]) // 10]),
                mib(mem["rss_bytes"][-1]),
                mib(m.memory.peak_rss_bytes),
                f"{th.backend_fps:.1f}",
                f"{th.latency_ms['backend'].p99:.1f}",
                f"{wall:.0f}",
            ]
        )
        print(
            "| " + " | ".join(head) + " |\n|" + "---|" * len(head) + "\n| " + " | ".join(map(str, rows[-1])) + " |",
            flush=True,
        )
    print("\n| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for row in rows:
        print("| " + " | ".join(str(v) for v in row) + " |")


def memory(laps: int, quiet: bool) -> None:
    """Accounted bytes by part against the RSS growth of a city-tour run of `laps` laps (after a warm-up)."""
    import tempfile

    spec = f"live:city-tour,sensor=hdl64,azimuth_steps=360,laps={laps}"
    with tempfile.TemporaryDirectory(prefix="msa-memory-") as store:
        base = dict(dataset=spec, odometry="gt-noise", sampler="msa", cloud_store="disk", store_dir=store)
        run(make_online_config(base, max_frames=300), quiet=quiet)  # warm-up: one-time costs
        t0 = time.perf_counter()
        r = run(make_online_config(base), quiet=quiet)
        wall = time.perf_counter() - t0
    m, mem = r.metrics, r.memory
    acc = m.memory.accounted
    series = sum(mem[k] for k in ("cloud_bytes", "descriptor_bytes", "graph_bytes", "record_bytes"))
    lap = len(series) // laps
    late_rss, late_acc = mem["rss_bytes"][-1] - mem["rss_bytes"][lap], series[-1] - series[lap]
    mib = lambda b: f"{b / 2**20:.1f}"  # noqa: E731
    print(f"\n{r.name}: {m.run.frames} frames, {m.run.keyframes} keyframes, {m.loops.verified} loops, {wall:.0f} s\n")
    print("| part | MiB |\n|---|---|")
    for label, value in [
        ("keyframe descriptors", acc.keyframe_descriptors),
        ("pose graph (GTSAM, iSAM2)", acc.graph),
        ("keyframe clouds in RAM", acc.keyframe_clouds - acc.clouds_on_disk),
        ("run records (per frame, loops)", acc.run_records),
        ("map", acc.map),
        ("accounted in RAM", acc.in_ram),
        ("(keyframe clouds on disk)", acc.clouds_on_disk),
        ("RSS growth over the run", m.memory.rss_growth_bytes),
    ]:
        print(f"| {label} | {mib(value)} |")
    print(f"| ratio RSS growth / accounted | {fmt(m.memory.rss_growth_ratio, '.2f')} |")
    print(
        f"| after lap 1: RSS growth / accounted growth | {mib(late_rss)} / {mib(late_acc)} = "
        f"{late_rss / late_acc:.2f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=None, help="first N scans (default: all)")
    parser.add_argument("--stride", type=int, default=3)
    parser.add_argument("--azimuth-steps", type=int, default=720)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--kiss-frames", type=int, default=30)
    parser.add_argument("--samplers", default=",".join(SAMPLERS))
    parser.add_argument("--scale", action="store_true", help="the long runs (KITTI-00, 22 km tour) instead")
    parser.add_argument("--memory", action="store_true", help="accounted bytes against RSS growth on the city tour")
    parser.add_argument("--laps", type=int, default=3, help="city-tour laps of --memory")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args()
    if args.memory:
        memory(args.laps, args.quiet)
        return
    if args.scale:
        scale(args.quiet)
        return
    spec = f"live:kitti-05,sensor=hdl64,stride={args.stride},azimuth_steps={args.azimuth_steps}"
    source = in_memory(spec, args.frames)
    n = len(source)
    kiss = kiss_rate(source, args.kiss_frames)
    print(f"KISS-ICP alone: {kiss * 1e3:.0f} ms per scan = {1 / kiss:.1f} frames/s (median of {args.kiss_frames - 1})")
    warm = make_online_config(dataset=spec, odometry="gt-noise", sampler="msa", max_frames=30)
    run(warm, LiveFrontEnd(source))  # compile the numba kernels outside the measured runs
    head = [
        "sampler",
        "keyframes",
        "loops",
        "back-end fps",
        "RTF",
        *[f"{s} ms" for s in STEPS[1:]],
        "p50 ms",
        "p99 ms",
        "max ms",
    ]
    rows = []
    for label in args.samplers.split(","):
        sampler, params = SAMPLERS[label]
        cfg = make_online_config(dataset=spec, odometry="gt-noise", sampler=sampler, sampler_params=params, label=label)
        runs = [run(cfg, LiveFrontEnd(source)) for _ in range(args.repeats)]
        pick = sorted(runs, key=lambda r: r.metrics.throughput.backend_fps)[len(runs) // 2]  # the median run
        m, th = pick.metrics, pick.metrics.throughput
        per_step = [statistics.median(float(r.steps_ms[s].sum()) / n for r in runs) for s in STEPS[1:]]
        lat = th.latency_ms["backend"]
        rows.append(
            [
                label,
                m.run.keyframes,
                m.loops.verified,
                f"{th.backend_fps:.1f}",
                f"{th.backend_fps / 10:.2f}",
                *[f"{v:.2f}" for v in per_step],
                f"{lat.p50:.1f}",
                f"{lat.p99:.1f}",
                f"{lat.max:.0f}",
            ]
        )
        print(
            f"  {label}: {th.backend_fps:.1f} fps (runs: "
            + ", ".join(f"{r.metrics.throughput.backend_fps:.1f}" for r in runs)
            + ")",
            flush=True,
        )
    print(f"\n{n} frames of {spec} (odometry: ground truth + noise; KISS-ICP: {1 / kiss:.1f} fps apart)\n")
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for row in rows:
        print("| " + " | ".join(str(v) for v in row) + " |")


if __name__ == "__main__":
    main()
