"""Per-stage wall time and accounted memory of the batch pipeline for each sampler (paper method set).

Default data: `sim:demo`, the simulated KITTI-05 trajectory (the whole 2.2 km, every 3rd frame: 921 scans)
with KISS-ICP odometry and Scan Context; the shared front end is computed once (or read from the cache)
and reported apart (`clouds`: every frame's downsampled cloud, which each method's keyframe_store copies). Times
are medians over --repeats runs of each method's back-end; "sampler/data" is the sampler's window-optimisation
time over the data's duration (metrics.json `sampler_realtime_fraction`), also a median.

    python benchmarks/bench_pipeline.py [--dataset sim:demo] [--repeats 3] [--mode oracle]
"""

from __future__ import annotations

import argparse
import statistics
import time

from msa_slam.evaluation.metrics import known
from msa_slam.experiments.compare import method_configs
from msa_slam.experiments.sweep import threshold_sweep
from msa_slam.pipeline import make_config, prepare_frontend, run
from msa_slam.pipeline.frontend import BACKEND_STAGES


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="sim:demo")
    parser.add_argument("--odometry", default="kiss")
    parser.add_argument("--mode", default="oracle")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cache-dir", default=None)
    args = parser.parse_args()

    base = make_config(dataset=args.dataset, odometry=args.odometry, mode=args.mode, cache_dir=args.cache_dir)
    start = time.perf_counter()
    frontend = prepare_frontend(base, quiet=True)
    n = len(frontend)
    print(
        f"dataset {args.dataset} ({frontend.name}): {n} frames, the whole trajectory "
        f"(front end ready in {time.perf_counter() - start:.1f} s)"
    )
    for stage, seconds in frontend.timer.seconds.items():
        state = "cached" if frontend.cached.get(stage) else f"{1e3 * seconds / n:.1f} ms/frame"
        print(f"  front end {stage:<12} {seconds:8.2f} s  ({state})")
    print(f"back-end medians over {args.repeats} runs, mode {args.mode}\n")

    columns = [
        "method",
        "kf",
        "cand",
        "ver",
        *BACKEND_STAGES,
        "total s",
        "sampler/data",
        "desc MiB",
        "clouds MiB",
        "graph KiB",
        "peak RSS MiB",
    ]
    print(" | ".join(columns))
    print("|".join("---" for _ in columns))
    for cfg in method_configs(base):
        runs = [run(cfg, frontend, sweep=threshold_sweep).metrics for _ in range(args.repeats)]
        m = runs[-1]
        med = {
            s: statistics.median(r.timing.stages.get(s, 0.0) for r in runs)  # the stages a batch run has
            for s in (*BACKEND_STAGES, "backend_total")
        }
        mem = m.memory.accounted
        fractions = [known(r.timing.sampler_realtime_fraction) for r in runs]
        fraction = "n/a" if None in fractions else f"{statistics.median(fractions):.4f}"
        row = [
            cfg.name,
            m.run.keyframes,
            m.loops.candidates,
            m.loops.verified,
            *(f"{med[s]:.2f}" for s in BACKEND_STAGES),
            f"{med['backend_total']:.2f}",
            fraction,
            f"{mem.keyframe_descriptors / 2**20:.2f}",
            f"{mem.keyframe_clouds / 2**20:.1f}",
            f"{mem.graph / 2**10:.0f}",
            f"{m.memory.peak_rss_bytes / 2**20:.0f}",
        ]
        print(" | ".join(map(str, row)), flush=True)


if __name__ == "__main__":
    main()
