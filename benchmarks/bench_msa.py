"""MSA speed: window optimisation time per mode, window size and descriptor shape, plus parity counts.

Streams are random walks in pose and descriptor space (256-d vectors and 20x60 Scan-Context-shaped
arrays), 240 frames, lambda_u = 3 (paper). The "one-at-a-time" column times a plain transcription of
the reference (msa_slam.sampling.msa.terms) on the same windows at N = 10, the reference's shape
of computation, so the speed-up is measured on this machine rather than quoted.

Usage: python benchmarks/bench_msa.py [--quick] [--canonical-only] [--repeats R]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
from pathlib import Path

import numba
import numpy as np
from numba import njit

from msa_slam.io.provenance import cpu_model
from msa_slam.sampling import make_sampler
from msa_slam.sampling.msa import ScoreWeights, fast, optimise_window
from msa_slam.sampling.msa.eigen import LANE_WORK, LANES, symmetric_eigh, symmetric_eigh_lanes
from msa_slam.sampling.msa.exact import ExactWorkspace
from msa_slam.sampling.msa.terms import optimise_window_literal

PARITY_DIR = Path(__file__).resolve().parents[2] / "shared" / "parity"
MSA_NAME = re.compile(r"msa_N(\d+)_nn(\d+)_a([\d.]+)_b([\d.]+)_l([\d.]+)_u([\d.]+)$")


def random_walk_stream(shape: tuple[int, ...], frames: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (frames, 1, 1))
    heading = np.cumsum(rng.normal(0, 0.1, frames))
    step = rng.uniform(0.6, 1.4, frames)
    poses[:, 0, 3] = np.cumsum(step * np.cos(heading))
    poses[:, 1, 3] = np.cumsum(step * np.sin(heading))
    desc = np.abs(np.cumsum(rng.standard_normal((frames, *shape)) * 0.3, axis=0))
    return poses, desc


def time_sampler(poses, desc, window: int, mode: str, pi: str = "reference"):
    """Median and p95 ms per window (wall), candidates per window, us per candidate (wall)."""
    sampler = make_sampler("msa", window=window, lambda_u=3.0, mode=mode, pi=pi)
    sampler.run(poses, desc)
    ms = np.array(sampler.stats.optimisation_ms)
    cands = sampler.stats.candidates_evaluated / max(sampler.stats.window_optimisations, 1)
    return float(np.median(ms)), float(np.percentile(ms, 95)), cands, float(np.median(ms)) * 1e3 / cands


def canonical_run(poses, desc, window: int, threads: int, parallel_from: int | None = None):
    """Canonical fast mode on `threads` numba threads: median ms per window (wall), candidates per
    window, and CPU us per candidate over the whole run (process time, all threads; less sensitive to
    other jobs than wall time). parallel_from overrides fast.PARALLEL_FROM (windows from that many
    candidates go to the threads)."""
    saved = fast.PARALLEL_FROM
    numba.set_num_threads(threads)
    if parallel_from is not None:
        fast.PARALLEL_FROM = parallel_from
    try:
        sampler = make_sampler("msa", window=window, lambda_u=3.0, mode="fast", pi="canonical")
        cpu = time.process_time()
        sampler.run(poses, desc)
        cpu = time.process_time() - cpu
    finally:
        fast.PARALLEL_FROM = saved
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    ms = float(np.median(sampler.stats.optimisation_ms))
    return (
        ms,
        sampler.stats.candidates_evaluated / max(sampler.stats.window_optimisations, 1),
        cpu * 1e6 / max(sampler.stats.candidates_evaluated, 1),
    )


def literal_speedup(poses, desc, window: int = 10, windows: int = 12):
    """Median ms per window: one-at-a-time transcription vs exact vs fast on the same windows."""
    t = poses[:, :3, 3]
    weights = ScoreWeights()
    workspace = ExactWorkspace()  # as the sampler keeps one across windows
    results = {"literal": [], "exact": [], "fast": []}
    starts = np.linspace(0, len(poses) - window, windows).astype(int)
    for s in starts:
        args = (t[s : s + window], desc[s : s + window], 0.1, 3.0)
        for name, call in (
            ("literal", lambda: optimise_window_literal(*args, weights)),
            ("exact", lambda: optimise_window(*args, weights, "exact", workspace)),
            ("fast", lambda: optimise_window(*args, weights, "fast")),
        ):
            t0 = time.perf_counter()
            call()
            results[name].append((time.perf_counter() - t0) * 1e3)
    return {k: float(np.median(v)) for k, v in results.items()}


@njit
def _lapack_each(cs):  # pragma: no cover
    total = 0.0
    for k in range(cs.shape[0]):
        total += np.linalg.eigh(cs[k])[0][0]
    return total


@njit
def _compiled_each(cs, v, d, e):  # pragma: no cover
    total = 0.0
    for k in range(cs.shape[0]):
        v[:, :] = cs[k]
        symmetric_eigh(v, d, e, cs.shape[1])
        total += d[0]
    return total


@njit
def _lanes_each(cs):  # pragma: no cover
    """symmetric_eigh_lanes on LANES matrices at a time (their copy into the lane-innermost layout included)."""
    m = cs.shape[1]
    v, d, e, work = np.empty((m, m, LANES)), np.empty((m, LANES)), np.empty((m, LANES)), np.empty((LANE_WORK, LANES))
    total = 0.0
    for start in range(0, cs.shape[0], LANES):
        count = min(LANES, cs.shape[0] - start)
        for i in range(m):
            for j in range(m):
                for lane in range(count):
                    v[i, j, lane] = cs[start + lane, i, j]
        symmetric_eigh_lanes(v, d, e, m, count, work)
        total += d[0, 0]
    return total


def eigensolver_timings(sizes=(3, 5, 9, 10, 13, 15, 19), count=2048, repeats=5):
    """Median us per matrix: LAPACK dsyevd (numba's np.linalg.eigh) vs msa.eigen on random C = X X^T,
    one matrix at a time and LANES at a time (what canonical pi runs)."""
    rows = []
    for m in sizes:
        x = np.random.default_rng(m).standard_normal((count, m, m))
        cs = x @ x.transpose(0, 2, 1)
        v, d, e = np.empty((m, m)), np.empty(m), np.empty(m)
        calls = {
            "dsyevd": lambda: _lapack_each(cs),
            "compiled": lambda: _compiled_each(cs, v, d, e),
            "lanes": lambda: _lanes_each(cs),
        }
        timing = {}
        for name, call in calls.items():
            call()
            runs = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                call()
                runs.append((time.perf_counter() - t0) / count * 1e6)
            timing[name] = float(np.median(runs))
        rows.append((m, timing["dsyevd"], timing["compiled"], timing["lanes"]))
    return rows


def parity_stream_timings():
    """Median ms per window at N = 10 on the parity streams, where the reference's cost is documented
    (docs/msa.md, "Limits and cost"; the reference: 55-61 ms on 256-d streams, 76 ms on the sc20x60 stream)."""
    rows = []
    for name in ("stream_s0_vec256.npz", "stream_s0_sc20x60.npz"):
        data = np.load(PARITY_DIR / name)
        for mode in ("exact", "fast"):
            med, p95, cands, us = time_sampler(data["poses"], data["descriptors"], 10, mode)
            rows.append((name, mode, med, p95, cands))
    return rows


def parity_counts():
    """Per mode and pi: MSA configurations identical to the reference, with an ambiguous window (and of
    those, how many still match fully), and differing without any ambiguous window (0 for pi=reference;
    canonical pi is another definition, its agreement is reported)."""
    counts = {}
    for mode, pi in (("exact", "reference"), ("fast", "reference"), ("fast", "canonical")):
        tally = {"identical": 0, "ambiguous": 0, "ambiguous_matching": 0, "differing": 0}
        for path in sorted(PARITY_DIR.glob("stream_*.npz")):
            data = np.load(path)
            for name, keyframes in json.loads(str(data["expected"])).items():
                match = MSA_NAME.match(name)
                if not match:
                    continue
                n, nb, a, b, lo, hi = match.groups()
                sampler = make_sampler(
                    "msa",
                    window=int(n),
                    neighbours=int(nb),
                    alpha=float(a),
                    beta=float(b),
                    lambda_l=float(lo),
                    lambda_u=float(hi),
                    mode=mode,
                    pi=pi,
                )
                same = sampler.run(data["poses"], data["descriptors"]) == keyframes
                if sampler.stats.ambiguous:
                    tally["ambiguous"] += 1
                    tally["ambiguous_matching"] += same
                else:
                    tally["identical" if same else "differing"] += 1
        counts[f"{mode}/{pi}"] = tally
    return counts


def canonical_targets(shapes, repeats: int = 3) -> None:
    """The window-time targets: median ms per window at N = 10, 16, 20, canonical vs reference (fast mode),
    canonical on 2 threads and on 1; at N = 10 also with every window handed to the threads (windows
    under fast.PARALLEL_FROM candidates run on the calling thread: this column is the data for that
    threshold). Each figure is the median over `repeats` sampler runs (2 and 1 threads alternating) of
    the run's median window, with the runs' range beside the 2-thread figure: on a shared machine one
    run's median moves by a quarter from run to run."""
    targets = {10: 0.5, 16: 10.0, 20: 100.0}
    most = numba.config.NUMBA_NUM_THREADS
    print(
        f"\nCanonical vs reference pi, fast mode (random-walk streams; reference refuses N > 16); "
        f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs ({cpu_model()}); ms per window: median over "
        f"{repeats} runs of each run's median window (wall)"
    )
    print(
        f"{'shape':8} {'N':>3} {'cand/window':>12} {'reference':>10} {f'canon. {most} thr':>13} "
        f"{'(range)':>15} {'canon. 1 thr':>13} {'all threaded':>13} {'run CPU us/c':>12} {'target ms':>10}"
    )
    for shape_name, shape in shapes.items():
        for n, target in targets.items():
            stream = random_walk_stream(shape, 240 if n <= 12 else 60)
            runs = {"reference": [], "both": [], "one": [], "handed": [], "cpu": []}
            for _ in range(repeats):
                if n <= 16:
                    runs["reference"].append(time_sampler(*stream, n, "fast")[0])
                both, cands, _ = canonical_run(*stream, n, most)
                one, _, cpu = canonical_run(*stream, n, 1)
                runs["both"].append(both)
                runs["one"].append(one)
                runs["cpu"].append(cpu)
                if n == 10:
                    runs["handed"].append(canonical_run(*stream, n, most, 0)[0])
            median = {key: float(np.median(values)) if values else None for key, values in runs.items()}
            reference = f"{median['reference']:>10.3f}" if median["reference"] is not None else f"{'n/a':>10}"
            spread = f"{min(runs['both']):.3f}-{max(runs['both']):.3f}"
            handed = f"{median['handed']:>13.3f}" if median["handed"] is not None else f"{'':>13}"
            print(
                f"{shape_name:8} {n:>3} {cands:>12.0f} {reference} {median['both']:>13.3f} {spread:>15} "
                f"{median['one']:>13.3f} {handed} {median['cpu']:>12.2f} {target:>10.1f}",
                flush=True,
            )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="N = 8, 10, 12 only; skip parity")
    parser.add_argument("--canonical-only", action="store_true", help="only the canonical-pi table")
    parser.add_argument(
        "--repeats",
        type=int,
        default=3,
        help="sampler runs per canonical-pi figure, reported as their median (default 3)",
    )
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats must be at least 1, got {args.repeats}")
    sizes = [8, 10, 12] if args.quick else list(range(8, 17))
    shapes = {"vec256": (256,), "sc20x60": (20, 60)}
    warm = random_walk_stream((16,), 40)
    for mode, pi in (("exact", "reference"), ("fast", "reference"), ("fast", "canonical")):  # compile first
        time_sampler(*warm, 8, mode, pi)
    canonical_targets(shapes, args.repeats)
    if args.canonical_only:
        return 0

    print("\nMSA window optimisation (random-walk streams, lambda_u = 3)")
    print(f"{'mode':6} {'shape':8} {'N':>3} {'median ms':>10} {'p95 ms':>9} {'cand/window':>12} {'us/cand':>8}")
    for mode in ("exact", "fast"):
        for shape_name, shape in shapes.items():
            for n in sizes:
                frames = 240 if n <= 12 else 120
                med, p95, cands, us = time_sampler(*random_walk_stream(shape, frames), n, mode)
                print(f"{mode:6} {shape_name:8} {n:>3} {med:>10.3f} {p95:>9.3f} {cands:>12.0f} {us:>8.2f}", flush=True)

    print("\nSpeed-up at N = 10 over a one-candidate-at-a-time transcription (same windows, median ms)")
    print(f"{'shape':8} {'one-at-a-time':>14} {'exact':>8} {'fast':>8} {'exact x':>8} {'fast x':>8}")
    for shape_name, shape in shapes.items():
        r = literal_speedup(*random_walk_stream(shape, 240))
        print(
            f"{shape_name:8} {r['literal']:>14.2f} {r['exact']:>8.2f} {r['fast']:>8.3f} "
            f"{r['literal'] / r['exact']:>8.1f} {r['literal'] / r['fast']:>8.1f}"
        )

    print(
        f"\nEigensolver per matrix (random C = X X^T, median us): LAPACK dsyevd vs msa/eigen.py, one matrix "
        f"at a time and {LANES} at a time"
    )
    print(f"{'m':>3} {'dsyevd':>8} {'compiled':>9} {'speed-up':>9} {'lanes':>8} {'speed-up':>9}")
    for m, lapack, compiled, lanes in eigensolver_timings():
        print(
            f"{m:>3} {lapack:>8.2f} {compiled:>9.2f} {lapack / compiled:>8.2f}x {lanes:>8.2f} {lapack / lanes:>8.2f}x",
            flush=True,
        )

    if args.quick:
        return 0
    if not PARITY_DIR.exists():
        print("\nparity: ../shared/parity not found, skipped")
        return 0
    print("\nN = 10 on the parity streams (reference: 55-61 ms for 256-d, 76 ms for sc20x60)")
    print(f"{'stream':22} {'mode':6} {'median ms':>10} {'p95 ms':>9} {'cand/window':>12} {'vs reference':>13}")
    for name, mode, med, p95, cands in parity_stream_timings():
        reference = 76.0 if "sc20x60" in name else 55.0
        print(f"{name:22} {mode:6} {med:>10.3f} {p95:>9.3f} {cands:>12.0f} {reference / med:>12.1f}x")
    counts = parity_counts()
    print("\nParity with the reference vectors (144 MSA configurations; ambiguous = a window whose choice")
    print("rounding could change, see sampling/msa/decision.py)")
    print(f"{'mode/pi':16} {'identical':>10} {'ambiguous':>10} {'(of which match)':>17} {'differing':>10}")
    for mode, c in counts.items():
        print(f"{mode:16} {c['identical']:>10} {c['ambiguous']:>10} {c['ambiguous_matching']:>17} {c['differing']:>10}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
