"""The fair comparison on the shipped KITTI trajectories: for each sequence and loop mode,
`compare --seeds` (every sampler of the paper, full-rate ATE so "ATE before" is the same for all) and one
table per sequence and mode: every sampler's full-rate translational ATE improvement (mean +- std over the
world seeds), RPE over KITTI's 100-800 m segments, PR-AUC and F1-max (the paper's database protocol),
keyframes, accepted and rejected loops, accounted memory, process RSS growth, MSA's rank per metric on each
seed, and the never-worse check (the worst full-rate improvement of any sampler on any seed, which must stay
above -5 %).

    python benchmarks/bench_fairness.py [--sequences 05,06] [--seeds 0,1,2] [--modes oracle,realistic]
                                        [--azimuth-steps 720] [--frames N] [--out DIR] [--cache-dir DIR]

Each comparison's full result folder (reports, figures, per-method runs) is kept under --out
(default: ./msa_slam_results/bench_fairness/), one per sequence and mode; a finished one over the same
seeds is reused as is; an interrupted one, or one finished on other seeds, is resumed (its finished seeds are
kept, the missing ones run); delete it, or pass a new --out, to rerun. Simulations, odometry and
descriptors are cached as everywhere else (the same simulated sequences as benchmarks/bench_realism.py at the
same azimuth steps).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from msa_slam.evaluation import fmt
from msa_slam.experiments.compare import run_compare
from msa_slam.pipeline import make_config

NEVER_WORSE_PCT = -5.0
COLUMNS = (
    ("improvement_t_pct", "t. ATE impr. %"),
    ("rpe_pct", "RPE %"),
    ("pr_auc", "PR-AUC"),
    ("f1_max", "F1-max"),
    ("keyframes", "keyframes"),
    ("verified", "loops"),
    ("rejected", "rejected"),
    ("false_loops", "false"),
    ("memory_mib", "memory MiB"),
    ("rss_growth_mib", "RSS growth MiB"),
)


def _cell(entry: dict, digits: str) -> str:
    if entry["mean"] is None:
        return "n/a"
    std = "" if entry["std"] is None else f" ± {fmt(entry['std'], digits)}"
    return f"{fmt(entry['mean'], digits)}{std}"


def comparison(dataset: str, mode: str, seeds: list[int], folder: Path, cache_dir: str | None) -> dict:
    """seeds.json of the comparison in `folder` over `seeds`: a finished one over the same seeds is read as is;
    otherwise run_compare runs it, resuming a folder killed part-way or finished on fewer seeds (the seeds
    that finished there are reused)."""
    done = folder / "seeds.json"
    if not done.is_file() or json.loads(done.read_text()).get("seeds") != seeds:
        cfg = make_config(dataset=dataset, mode=mode, cache_dir=cache_dir)
        run_compare(cfg, folder, quiet=True, seeds=seeds)
    return json.loads(done.read_text())


def print_table(title: str, summary: dict) -> None:
    metrics = summary["metrics"]
    methods = list(metrics["improvement_t_pct"]["methods"])
    print(
        f"\n### {title} (seeds {', '.join(map(str, summary['seeds']))}; mean ± std over seeds; full-rate ATE, "
        "Umeyama SE(3) alignment on every frame)\n"
    )
    print("| method | " + " | ".join(label for _, label in COLUMNS) + " |")
    print("|" + "---|" * (len(COLUMNS) + 1))
    for m in methods:
        cells = [
            _cell(metrics[key]["methods"][m], ".3f" if key in ("pr_auc", "f1_max") else ".1f") for key, _ in COLUMNS
        ]
        print(f"| {m} | " + " | ".join(cells) + " |")
    ranked = [(key, label) for key, label in COLUMNS if metrics[key]["higher_is_better"] is not None]
    ranks = [
        "/".join("n/a" if r is None else str(r) for r in metrics[key]["methods"]["msa"]["ranks"]) for key, _ in ranked
    ]
    print("\nMSA's rank per seed (1 = best of 7): " + "; ".join(f"{label} {r}" for (_, label), r in zip(ranked, ranks)))
    verdicts = {b: v["verdict"] for b, v in metrics["improvement_t_pct"]["msa_vs"].items()}
    print(
        "MSA vs each baseline on t. ATE improvement ("
        + summary["test"]
        + "): "
        + "; ".join(f"{b}: {v}" for b, v in verdicts.items())
    )
    worst = min(
        (v for m in methods for v in metrics["improvement_t_pct"]["methods"][m]["values"] if v is not None),
        default=None,
    )
    verdict = "n/a" if worst is None else ("ok" if worst >= NEVER_WORSE_PCT else "VIOLATED")
    print(
        f"never worse than odometry by more than 5 %: worst sampler-seed improvement {fmt(worst, '.1f', ' %')} "
        f"-> {verdict}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", default="05,06")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--modes", default="oracle,realistic")
    parser.add_argument("--azimuth-steps", type=int, default=720, help="HDL-64 azimuth steps (bench_realism: 720)")
    parser.add_argument("--frames", type=int, default=None, help="a prefix of each sequence (default: whole)")
    parser.add_argument("--out", type=Path, default=Path("msa_slam_results/bench_fairness"))
    parser.add_argument("--cache-dir", default=None)
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)
    for seq in args.sequences.split(","):
        fields = [f"azimuth_steps={args.azimuth_steps}"] + ([f"end={args.frames}"] if args.frames else [])
        dataset = f"sim:kitti-{seq}," + ",".join(fields)
        for mode in args.modes.split(","):
            start = time.perf_counter()
            summary = comparison(dataset, mode, seeds, args.out / f"kitti-{seq}-{mode}", args.cache_dir)
            print_table(f"KITTI-{seq}, {mode} loops, {args.frames or 'all'} frames at 10 Hz", summary)
            print(
                f"({time.perf_counter() - start:.0f} s; result folder {args.out / f'kitti-{seq}-{mode}'})", flush=True
            )


if __name__ == "__main__":
    main()
