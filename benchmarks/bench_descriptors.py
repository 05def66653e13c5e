"""Descriptor and loop-search speed: extraction per scan, query time vs database size, two-stage recall.

Run: .venv/bin/python benchmarks/bench_descriptors.py [--sizes 1000 10000 100000] [--ot-weights PATH]
Real scans: ../shared/data/kitti_scans_00 (KITTI, Geiger et al., CVPR 2012). Medians over repeats.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from msa_slam.descriptors.range_image import range_projection
from msa_slam.descriptors.scan_context import ScanContext
from msa_slam.descriptors.voxel import voxel_downsample
from msa_slam.place_recognition import KeyframeDatabase

SCANS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_scans_00"
console = Console(width=150)


def median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def load_scans() -> list[np.ndarray]:
    return [np.fromfile(p, dtype=np.float32).reshape(-1, 4) for p in sorted(SCANS.glob("*.bin"))]


def bench_extraction(scans: list[np.ndarray], ot_weights: str | None) -> None:
    sc = ScanContext()
    sc.compute(scans[0])  # numba compile / cache load
    table = Table(title="Extraction per real KITTI scan (median ms)")
    for col in ("scan", "points", "voxels", "downsample", "binning", "SC total", "OT (CPU)"):
        table.add_column(col, justify="right")
    ot = _ot_model(ot_weights)
    for k, scan in enumerate(scans):
        down = voxel_downsample(scan)
        ot_ms = "torch absent"
        if ot is not None:
            ot.compute(scan)
            ot_ms = f"{median_ms(lambda: ot.compute(scan), 5):.1f}"
        table.add_row(
            str(k),
            str(len(scan)),
            str(len(down)),
            f"{median_ms(lambda: voxel_downsample(scan), 30):.2f}",
            f"{median_ms(lambda: sc.bin(down), 30):.2f}",
            f"{median_ms(lambda: sc.compute(scan), 30):.2f}",
            ot_ms,
        )
    console.print(table)
    if ot is not None:
        console.print(
            f"  OT: range projection alone {median_ms(lambda: range_projection(scans[0]), 10):.1f} ms; "
            f"weights: {ot_weights or 'random (timing only; pass --ot-weights for the authors checkpoint)'}"
        )


def _ot_model(weights: str | None):
    """OverlapTransformer from the given checkpoint, or from random weights (timing only) if none."""
    try:
        import torch
    except ImportError:
        return None
    from msa_slam.descriptors._ot_network import OverlapTransformerNet
    from msa_slam.descriptors.overlap_transformer import OverlapTransformer

    if weights:
        return OverlapTransformer(weights)
    rng = np.random.default_rng(0)
    state = {
        name: torch.from_numpy(rng.normal(0, 0.02, t.shape).astype(np.float32))
        for name, t in OverlapTransformerNet().state_dict().items()
    }
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "random_weights.pth"
        torch.save({"state_dict": state}, path)
        return OverlapTransformer(path)


def random_walk_bank(base: np.ndarray, n: int, seed: int) -> np.ndarray:
    """n Scan Contexts along a 'drive': a real descriptor's occupied cells drift by a random walk
    (step 0.05 m, pulled back towards the real heights), cells appear/vanish, yaw changes slowly.
    Consecutive entries look alike, distant ones do not, like keyframes of one sequence."""
    rng = np.random.default_rng(seed)
    out = np.empty((n, *base.shape))
    field = np.zeros(base.shape)
    occupied = base > 0
    yaw = 0.0
    for i in range(n):
        field = 0.995 * field + rng.normal(0, 0.05, base.shape)
        flip = rng.random(base.shape) < 0.002
        occupied = occupied ^ flip
        yaw += rng.normal(0, 0.5)
        out[i] = np.roll(np.where(occupied, np.maximum(base + 4.0 * field, 0.0), 0.0), int(yaw) % 60, axis=1)
    return out


def revisit_queries(bank: np.ndarray, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Revisits of random stored places: height noise 0.1 m, 5% of cells lost, arbitrary yaw."""
    rng = np.random.default_rng(seed)
    targets = rng.integers(0, len(bank), n)
    queries = bank[targets] + rng.normal(0, 0.1, (n, *bank.shape[1:])) * (bank[targets] > 0)
    queries *= rng.random(queries.shape) > 0.05
    queries = np.stack([np.roll(q, int(rng.integers(60)), axis=1) for q in np.maximum(queries, 0.0)])
    return queries, targets


def bench_queries(base: np.ndarray, sizes: list[int], n_queries: int) -> None:
    sc = ScanContext()
    table = Table(title="Loop query vs database size (Scan Context 20x60, all 60 shifts)")
    for col in (
        "keyframes",
        "exhaustive ms",
        "two-stage ms",
        "tree build ms",
        "recall@1 2-stage(10) vs exh.",
        "recall@1 2-stage(50) vs exh.",
        "exh. finds revisit",
        "2-stage(10) finds revisit",
        "bytes/keyframe",
    ):
        table.add_column(col, justify="right")
    for n in sizes:
        bank = random_walk_bank(base, n, seed=n)
        db = KeyframeDatabase(sc, search="exhaustive", n_candidates=10)
        for i, d in enumerate(bank):
            db.add(i, np.eye(4), d)
        queries, targets = revisit_queries(bank, n_queries, seed=1)
        t = time.perf_counter()
        db.query(n + 1, queries[0], search="two_stage", threshold=0.0)  # builds the ring-key tree
        build_ms = 1e3 * (time.perf_counter() - t)
        reps = max(3, min(n_queries, 200_000 // n))
        exh_ms = median_ms(lambda: db.query(n + 1, queries[0], search="exhaustive", threshold=0.0), reps)
        two_ms = median_ms(lambda: db.query(n + 1, queries[0], search="two_stage", threshold=0.0), 50)
        agree = agree50 = exh_hit = two_hit = 0
        for q, target in zip(queries, targets):
            e = db.query(n + 1, q, search="exhaustive", threshold=0.0)[0].keyframe_id
            s = db.query(n + 1, q, search="two_stage", threshold=0.0)[0].keyframe_id
            agree += e == s
            agree50 += e == db.query(n + 1, q, search="two_stage", n_candidates=50, threshold=0.0)[0].keyframe_id
            exh_hit += abs(e - target) <= 2
            two_hit += abs(s - target) <= 2
        m = len(queries)
        table.add_row(
            f"{n:,}",
            f"{exh_ms:.1f}",
            f"{two_ms:.2f}",
            f"{build_ms:.0f}",
            f"{agree / m:.3f}",
            f"{agree50 / m:.3f}",
            f"{exh_hit / m:.3f}",
            f"{two_hit / m:.3f}",
            f"{db.bytes_per_keyframe:.0f}",
        )
        del db, bank
    console.print(table)
    console.print(
        "  Descriptors: random walk from a real KITTI Scan Context (see random_walk_bank); queries are noisy,\n"
        "  partly occluded, arbitrarily yawed copies of random stored entries. recall@1 = share of queries\n"
        "  where the two-stage top-1 (ring-key cKDTree, 10 candidates) equals the exhaustive top-1; 'finds\n"
        "  revisit' = top-1 within 2 entries of the copied one. bytes/keyframe: id + pose + 20x60 float64 + ring key."
    )


def bench_pairwise(base: np.ndarray) -> None:
    """The authors' per-pair similarity (60 np.roll calls) vs the batched matmul, for scale."""
    sc = ScanContext()
    b = np.roll(base, 11, axis=1)

    def per_pair() -> float:
        na, nb = np.linalg.norm(base), np.linalg.norm(b)
        return max(float(np.sum(np.roll(base, k, axis=1) * b)) / (na * nb) for k in range(60))

    console.print(
        f"Pairwise similarity: np.roll loop {median_ms(per_pair, 200):.3f} ms/pair, "
        f"ScanContext.similarity {median_ms(lambda: sc.similarity(base, b), 200):.3f} ms/pair"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1_000, 10_000, 100_000])
    parser.add_argument("--queries", type=int, default=100)
    parser.add_argument("--ot-weights", default=None, help="authors' OverlapTransformer checkpoint (optional)")
    args = parser.parse_args()
    scans = load_scans()
    if not scans:
        raise SystemExit(f"no KITTI scans found in {SCANS}")
    bench_extraction(scans, args.ot_weights)
    base = ScanContext().compute(scans[0])
    bench_pairwise(base)
    bench_queries(base, args.sizes, args.queries)
    ot_bytes = KeyframeDatabase(_PlainVector())
    ot_bytes.add(0, np.eye(4), np.zeros(256))
    console.print(f"bytes/keyframe with a 256-d descriptor (OverlapTransformer): {ot_bytes.bytes_per_keyframe:.0f}")


class _PlainVector:
    """Stand-in with OverlapTransformer's storage layout (256 float64) for the memory line."""

    name = "vector256"

    def similarity_many(self, query, bank):
        return 1.0 / (1.0 + np.linalg.norm(bank - query, axis=1))


if __name__ == "__main__":
    main()
