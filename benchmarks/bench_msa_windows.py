"""MSA past the paper's window: the benchmark's metrics for MSA alone with window N = 10, 16, 20 and
pi "reference" vs "canonical" on one simulated KITTI sequence, over world seeds, so users can see whether a
larger window or a machine-independent pi changes the answer.

    python benchmarks/bench_msa_windows.py [--sequence 06] [--seeds 0,1,2] [--windows 10,16,20]
                                           [--mode oracle|realistic] [--frames N] [--exact-up-to 10]
                                           [--out DIR] [--cache-dir DIR]

Every row is one MSA configuration run through the batch pipeline of `msa-slam run`/`compare` (the same
odometry, descriptors and loop settings; only the sampler's window, pi and mode differ), as the cells of an
experiment grid (msa_slam.experiments): each run's result folder is kept under --out/cells/, and a rerun
skips the finished ones, so an interrupted benchmark resumes. The table goes to stdout and --out/table.md.

MSA mode per row: "exact" (the reference's arithmetic, the pipeline's default) up to --exact-up-to members,
"fast" beyond (exact costs ~5 s a window at N = 16 with Scan Context); N <= --exact-up-to gets a fast row as
well, so that among the fast rows the window is the only change. A combination the sampler refuses (the
reference's pi stops at 16 members in any mode) is printed as n/a with the sampler's reason.

neighbours = 0, the pipeline's MSA default (compare's `msa` row): a window then holds N members. neighbours = 1
is the same (the nearest old keyframe is never joined); the authors' example uses 2, which adds one member:
N = 20 would hold 21 and be refused even in canonical fast mode (limit 20), N = 16 with reference pi 17 (limit 16).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from msa_slam.errors import InputError
from msa_slam.evaluation import ATE_ALIGNMENT, NA, fmt
from msa_slam.evaluation.run_metrics import RunMetrics
from msa_slam.evaluation.spread import spreads
from msa_slam.experiments.folder import cell_dir, read_cell
from msa_slam.experiments.grid import GridSpec, SamplerSpec, expand
from msa_slam.experiments.runner import run_grid
from msa_slam.experiments.seeds import parse_seeds
from msa_slam.io.atomic import write_text_atomic
from msa_slam.reporting.comparison import table_row
from msa_slam.sampling import make_sampler

NEIGHBOURS = 0
PIS = ("reference", "canonical")
BASELINE = (10, "reference", "exact")  # the pipeline's default MSA: keyframe agreement is measured against it
# (row key, header, format); the keys are those of `row_values`
COLUMNS = (
    ("keyframes", "keyframes", ".1f"),
    ("verified", "loops", ".1f"),
    ("improvement_t_pct", "t. ATE impr. %", ".1f"),
    ("rpe_pct", "RPE %", ".2f"),
    ("pr_auc", "PR-AUC", ".3f"),
    ("memory_mib", "memory MiB", ".1f"),
    ("window_ms", "ms / window", ".1f"),
    ("ambiguous", "ambiguous windows", ".1f"),
    ("jaccard_pct", "kf Jaccard vs N=10 ref. %", ".1f"),
)


@dataclass(frozen=True)
class Variant:
    """One row: MSA with window N, a pi definition and a mode; `refused` holds the sampler's reason."""

    window: int
    pi: str
    mode: str
    refused: str | None = None

    @property
    def key(self) -> tuple[int, str, str]:
        return self.window, self.pi, self.mode

    @property
    def label(self) -> str:
        return f"msa N={self.window} pi={self.pi} {self.mode}"

    @property
    def params(self) -> dict[str, Any]:
        return {"window": self.window, "pi": self.pi, "mode": self.mode, "neighbours": NEIGHBOURS}


def variants(windows: Sequence[int], exact_up_to: int) -> list[Variant]:
    """The rows for `windows`: exact and fast mode up to `exact_up_to`, fast beyond; each checked by the
    sampler itself, a refused one carrying its one-line reason."""
    out = []
    for window in windows:
        for pi in PIS:
            for mode in ("exact", "fast") if window <= exact_up_to else ("fast",):
                reason = None
                try:
                    make_sampler("msa", window=window, pi=pi, mode=mode, neighbours=NEIGHBOURS)
                except InputError as exc:
                    reason = str(exc)
                out.append(Variant(window, pi, mode, reason))
    return out


def jaccard_pct(a: Sequence[int], b: Sequence[int]) -> float:
    """100 |A & B| / |A | B| of two keyframe sets (100 for two empty sets)."""
    sa, sb = set(a), set(b)
    return 100.0 * len(sa & sb) / len(sa | sb) if sa | sb else 100.0


def chance_jaccard_pct(keyframes: float, frames: float) -> float:
    """The Jaccard (%) two random sets of `keyframes` of `frames` frames have on average, k / (2n - k): the
    level keyframe agreement should be read against when keyframes are dense (KITTI at 10 Hz: ~every 2nd)."""
    return 100.0 * keyframes / (2 * frames - keyframes)


def row_values(metrics: RunMetrics) -> dict[str, Any]:
    """A run's table values: compare's columns plus the MSA statistics and the keyframe frames (of the cell's
    metrics.json, which records them)."""
    stats = metrics.sampler_stats
    return {
        **table_row(metrics).record(),
        "frames": metrics.run.frames,
        "window_ms": stats["optimisation_ms_median"],
        "ambiguous": stats["ambiguous_windows"],
        "keyframe_frames": list(metrics.stamp.keyframe_frames),
    }


def _cell(values: Sequence[float | None], spec: str) -> str:
    spread = spreads([{"v": v} for v in values], None)["v"]
    if spread.mean is None:
        return NA
    return fmt(spread.mean, spec) + ("" if spread.std is None else f" ± {fmt(spread.std, spec)}")


def table_markdown(
    rows: Sequence[Variant],
    runs: Mapping[tuple[int, str, str], Mapping[int, Mapping[str, Any]]],
    seeds: Sequence[int],
    failed: Mapping[tuple[int, str, str], str] | None = None,
) -> str:
    """The table: one line per variant, each column mean ± std (ddof 1) over the seeds that finished
    (`runs`: variant key -> seed -> row_values); refused or failed variants as n/a with the reason."""
    failed = failed or {}
    base = runs.get(BASELINE, {})
    head = ["N", "pi", "MSA mode", *(h for _, h, _ in COLUMNS), "seeds"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for v in rows:
        done = runs.get(v.key, {})
        reason = v.refused or failed.get(v.key) or ("" if done else "not run")
        if not done:
            lines.append(
                f"| {v.window} | {v.pi} | {v.mode} | "
                + " | ".join([f"n/a: {reason}"] + [NA] * (len(COLUMNS) - 1))
                + f" | {NA} |"
            )
            continue
        per_seed = [
            {
                **done[s],
                "jaccard_pct": jaccard_pct(done[s]["keyframe_frames"], base[s]["keyframe_frames"])
                if s in base
                else None,
            }
            for s in seeds
            if s in done
        ]
        cells = [_cell([r[key] for r in per_seed], spec) for key, _, spec in COLUMNS]
        note = f" ({reason})" if reason else ""
        lines.append(
            f"| {v.window} | {v.pi} | {v.mode} | "
            + " | ".join(cells)
            + f" | {', '.join(str(s) for s in seeds if s in done)}{note} |"
        )
    return "\n".join(lines) + "\n"


def header(sequence: str, frames: int | None, seeds: Sequence[int], mode: str, runs: Mapping) -> str:
    """The conditions the table was measured under, in one line."""
    counts = sorted({r["frames"] for per_seed in runs.values() for r in per_seed.values()})
    n = "/".join(map(str, counts)) or "?"
    return (
        f"MSA alone on simulated KITTI-{sequence} (`kitti` realism, HDL-64 with 720 azimuth steps, 10 Hz), "
        f"{'all ' if frames is None else 'the first '}{n} frames, world seeds {', '.join(map(str, seeds))}, "
        f"{mode} loops, KISS-ICP odometry, Scan Context; MSA neighbours={NEIGHBOURS}; full-rate ATE after "
        f"{ATE_ALIGNMENT} alignment on every frame; RPE over KITTI's 100-800 m segments; PR-AUC of the paper's "
        "protocol; memory: accounted keyframe clouds + descriptors + graph; ms / window: median wall time of "
        "one window optimisation (the machine is shared); kf Jaccard: keyframe sets against N=10, reference "
        "pi, exact mode on the same seed; mean ± std (ddof 1) over seeds"
    )


def grid_for(
    variants_: Sequence[Variant],
    sequence: str,
    seeds: Sequence[int],
    mode: str,
    frames: int | None,
    cache_dir: str | None,
) -> GridSpec:
    """The experiment grid of the runnable variants: the batch pipeline on one simulated sequence, MSA only."""
    base: dict[str, Any] = {"mode": mode, "cache_dir": cache_dir}
    if frames is not None:
        base["source"] = {"frames": frames}
    runnable = [v for v in variants_ if v.refused is None]
    labels = [v.label for v in runnable]
    return GridSpec(
        name="msa_windows",
        pipeline="batch",
        datasets=[f"sim:kitti-{sequence},azimuth_steps=720,seed={{seed}}"],
        samplers=[SamplerSpec(sampler="msa", label=v.label, params=v.params) for v in runnable],
        seeds=list(seeds),
        base=base,
        reference=Variant(*BASELINE).label if Variant(*BASELINE).label in labels else None,
    )


def run(args: argparse.Namespace) -> str:
    """Run (or resume) the grid into args.out and return the table text (also written to args.out/table.md)."""
    seeds = parse_seeds(args.seeds)
    try:
        windows = [int(w) for w in args.windows.split(",")]
    except ValueError:
        raise InputError(f"--windows {args.windows!r}: expected comma-separated integers, e.g. 10,16,20") from None
    sequence = args.sequence.removeprefix("kitti-")
    rows = variants(windows, args.exact_up_to)
    grid = grid_for(rows, sequence, seeds, args.mode, args.frames, args.cache_dir)
    start = time.perf_counter()
    done = run_grid(grid, args.out, quiet=True)
    by_label = {v.label: v.key for v in rows}
    runs: dict[tuple[int, str, str], dict[int, dict[str, Any]]] = {}
    failed: dict[tuple[int, str, str], str] = {}
    for cell in expand(grid):
        found = read_cell(cell_dir(done.out, cell.id))
        if found is not None:
            runs.setdefault(by_label[cell.method], {})[cell.seed] = row_values(found.metrics)
        elif cell.id in done.failed:
            key = by_label[cell.method]
            failed[key] = "; ".join(filter(None, [failed.get(key), f"seed {cell.seed}: {done.failed[cell.id]}"]))
    base = list(runs.get(BASELINE, {}).values())
    chance = (
        f"\nChance level of the Jaccard column: two random keyframe sets of the N=10 reference row's size "
        "would share "
        f"{fmt(sum(chance_jaccard_pct(r['keyframes'], r['frames']) for r in base) / len(base), '.1f')} % "
        "(mean over seeds).\n"
        if base
        else ""
    )
    text = (
        header(sequence, args.frames, seeds, args.mode, runs)
        + "\n\n"
        + table_markdown(rows, runs, seeds, failed)
        + chance
        + f"\n{len(done.ran)} runs now, {len(done.skipped)} reused; {time.perf_counter() - start:.0f} s wall, "
        f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}; run folders: {done.out / 'cells'}\n"
    )
    write_text_atomic(done.out / "table.md", text)
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequence", default="06", help="shipped KITTI trajectory (00, 05, 06, 07, 09)")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--windows", default="10,16,20")
    parser.add_argument("--mode", choices=("oracle", "realistic"), default="oracle", help="loop verification")
    parser.add_argument("--frames", type=int, default=None, help="the first N frames (default: whole sequence)")
    parser.add_argument("--exact-up-to", type=int, default=10, help="largest N run in exact mode (default 10)")
    parser.add_argument("--out", type=Path, default=Path("msa_slam_results/bench_msa_windows"))
    parser.add_argument("--cache-dir", default=None)
    try:
        print(run(parser.parse_args()), flush=True)
    except InputError as exc:
        raise SystemExit(f"error: {exc}") from None


if __name__ == "__main__":
    main()
