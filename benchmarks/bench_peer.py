"""msa-slam against the peer, KISS-SLAM (PRBonn: KISS-ICP + local maps + MapClosures + pose graph), on the same
simulated scans: per sequence and world seed, the APE of KISS-ICP alone, KISS-SLAM and each msa-slam method,
with the wall time of each.

    python benchmarks/bench_peer.py [--sequences 07,09] [--seeds 0] [--end N] [--methods msa,constant-2m]
                                    [--peer-python PATH] [--peer-threads 1] [--peer-methods icp,slam,slam-raw]
                                    [-p KEY=VALUE ...] [--label NAME] [--out DIR] [--cache-dir DIR]
                                    [--speed [--speed-repeats 3] [--speed-jobs peer,run,compare]]

Each sequence is simulated once per seed as a KITTI-layout folder (`msa-slam simulate --trajectory NAME
--seed S [--end N] --out DIR/data/...`, per-point times in velodyne_times/; a sequence given as a number is
kitti-NN, any other name is a simulator trajectory). `-p` overrides msa-slam's run configuration as the
commands' `-p` does (e.g. `-p loop_detector=local-map`); give such a run a `--label`, under which its
comparisons are kept apart from the default's (the peer's runs and the scans are shared). msa-slam runs `compare --mode
realistic --no-sweep` on that folder (the paper's method set, or --methods); the peer runs through
benchmarks/peer_kiss_slam.py with the Python that has kiss-slam (--peer-python; kiss-slam pins numpy and
pydantic older than msa-slam's, so it lives in its own venv), given the same scans and per-point times.

APE: evo, SE(3) Umeyama alignment (rotation + translation, no scale) fitted on every frame, translation RMSE over
every frame (msa-slam: the full-rate trajectory, trajectories/optimised.kitti) against the simulator's ground
truth; rotation RMSE beside it. Time: KISS-ICP and KISS-SLAM, the seconds of their processing (scans' reading
excluded) with --peer-threads KISS-ICP threads; msa-slam, the shared front end (odometry with 1 thread, Scan
Context) plus the method's back end (sampling, loop search, verification, optimisation), each from its
metrics.json (a front end read from the cache counts the time it took when computed).
Deskewing differs and is printed with the table: given the per-point times, the peer deskews (its default) to
the sweep's end, so its APE is taken against the ground truth interpolated to each sweep's end (the simulator's
truth is of mid-sweep; the mid-sweep figure is printed beside it); "KISS-SLAM, no per-point times" is
the peer as its CLI runs on .bin scans, without deskewing; msa-slam's odometry deskews to mid-sweep by default
when the scans carry per-point times, as the simulator's do (`-p odometry.deskew=false` turns it off), which
the table says from the run's metrics.json.

--speed times the end-to-end jobs instead (benchmarks/peer_timing.py): KISS-SLAM, `msa-slam run --sampler msa`
and `msa-slam compare`, each from a cold cache, wall and CPU time and peak RSS, medians of alternating repeats,
with the APE of each job's trajectory and its wall time as a share of KISS-SLAM's (--out/table-speed.md).

Results are kept under --out (default ./msa_slam_results/bench_peer/): a finished comparison or peer run is
reused on a rerun (delete it to rerun); the table goes to stdout and --out/table.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from peer_timing import JOBS, median_timing, timed_jobs

from msa_slam.evaluation import ATE_ALIGNMENT, fmt
from msa_slam.evaluation.metrics import known as number_or_none
from msa_slam.evaluation.metrics_json import from_json
from msa_slam.evaluation.trajectory import ate
from msa_slam.experiments.compare import PAPER_METHODS, run_compare
from msa_slam.io.poses import read_poses
from msa_slam.io.provenance import cpu_model
from msa_slam.pipeline import make_config
from msa_slam.pipeline.config import RunConfig, apply_overrides
from msa_slam.sim.trajectories import interpolate_poses
from msa_slam.viz.labels import counted

DRIVER = Path(__file__).with_name("peer_kiss_slam.py")
CLI = "import sys; from msa_slam.cli import main; sys.argv = ['msa-slam', *sys.argv[1:]]; main()"
INSTALL = (
    "KISS-SLAM (the peer) is not installed for {python}: {error}\n"
    "Install it into its own venv (kiss-slam pins numpy and pydantic older than msa-slam's):\n"
    "    python3 -m venv peer-venv && peer-venv/bin/pip install 'kiss-slam>=0.0.2'\n"
    "    (open3d, which kiss-slam imports, needs libusb: apt-get install libusb-1.0-0)\n"
    "then pass --peer-python peer-venv/bin/python (or set MSA_SLAM_PEER_PYTHON). "
    "The peer's rows are n/a until then."
)


def trajectory_name(sequence: str) -> str:
    """The simulator trajectory of a --sequences entry: a number is a KITTI sequence, a name is itself."""
    sequence = sequence.strip()
    return f"kitti-{sequence.zfill(2)}" if sequence.isdigit() else sequence


def run_name(sequence: str, seed: int, end: int | None) -> str:
    return f"{trajectory_name(sequence)}-seed{seed}" + ("" if end is None else f"-end{end}")


def peer_missing(python: str) -> str | None:
    """Why `python` cannot run KISS-SLAM (None when it can)."""
    try:
        done = subprocess.run([python, "-c", "import kiss_slam.slam, kiss_icp"], capture_output=True, text=True)
    except OSError as exc:
        return str(exc)
    lines = done.stderr.strip().splitlines()
    return None if done.returncode == 0 else (lines[-1] if lines else f"exit status {done.returncode}")


def simulated(sequence: str, seed: int, end: int | None, root: Path) -> Path:
    """The KITTI-layout folder of the simulated sequence, made once: `msa-slam simulate` reuses a complete
    folder of this simulator version and configuration, resumes its own partial one, and refuses any other
    (scans of an older SIM_VERSION included: they would be timed as this code's)."""
    folder = root / run_name(sequence, seed, end)
    command = [
        sys.executable,
        "-c",
        CLI,
        "simulate",
        "--trajectory",
        trajectory_name(sequence),
        "--seed",
        str(seed),
        "--out",
        str(folder),
        "--quiet",
        *([] if end is None else ["--end", str(end)]),
    ]
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return folder


# --peer-methods: (row label, peer_kiss_slam.py method, its extra arguments, conditions)
PEER_RUNS = {
    "icp": ("KISS-ICP (peer config)", "icp", [], "deskew to sweep end"),
    "slam": ("KISS-SLAM", "slam", [], "deskew to sweep end"),
    "slam-raw": ("KISS-SLAM, no per-point times", "slam", ["--no-times"], "no deskew (as its CLI reads .bin scans)"),
}


def peer_run(python: str, method: str, folder: Path, out: Path, threads: int, extra: list[str]) -> dict:
    """The peer's poses and seconds (from peer_kiss_slam.py, run once and kept in `out`)."""
    if not out.is_file():
        tmp = out.with_suffix(".partial.npz")
        start = time.perf_counter()
        done = subprocess.run(
            [python, str(DRIVER), method, str(folder), str(tmp), "--threads", str(threads), *extra],
            capture_output=True,
            text=True,
        )  # the peer's optimiser prints every iteration
        wall = time.perf_counter() - start
        if done.returncode:
            raise RuntimeError(
                f"{DRIVER.name} {method} failed (exit status {done.returncode}):\n"
                + "\n".join(done.stderr.splitlines()[-20:])
            )
        with np.load(tmp) as data:
            np.savez(out, **data, wall=np.float64(wall))
        tmp.unlink()
    with np.load(out) as data:
        return {k: data[k] for k in data}


def compared(
    folder: Path, out: Path, methods: list[tuple], cache_dir: Path, params: list[str]
) -> tuple[Path, float | None]:
    """msa-slam's comparison folder (run once) and its wall seconds (None when reused); `params`: -p overrides."""
    if (out / "comparison.csv").is_file():
        return out, None
    data = make_config(dataset=str(folder), mode="realistic", cache_dir=str(cache_dir)).dump()
    cfg = make_config(apply_overrides(data, params, RunConfig))
    start = time.perf_counter()
    run_compare(cfg, out, quiet=True, methods=methods, sweep=False, overwrite=out.exists())
    return out, time.perf_counter() - start


def deskew_note(odometry_config: dict) -> str:
    """How msa-slam's odometry treated motion distortion (its `deskew` setting)."""
    return "deskew to mid-sweep" if odometry_config.get("data", {}).get("deskew") else "no deskew"


def sweep_end_truth(gt: np.ndarray, stamps: np.ndarray) -> np.ndarray:
    """Ground truth at each sweep's end: the simulator's poses are those of mid-sweep (KITTI's convention), the
    sweep spans one frame period centred on its stamp, and the peer deskews to the sweep's end, so its poses are
    compared with the truth half a period later (interpolated; the last frame extrapolated at constant velocity).
    Without this the peer would carry an along-track error of half a sweep that is a convention, not drift."""
    half = 0.5 * float(np.median(np.diff(stamps)))
    return interpolate_poses(gt, stamps, stamps + half)


def ape(estimate: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (deg) RMSE after SE(3) Umeyama alignment on every frame (evo)."""
    error = ate(estimate, gt)
    return error.translation_rmse, error.rotation_rmse


def rows_for(sequence: str, seed: int, args: argparse.Namespace, peer: str | None) -> tuple[list[dict], dict]:
    """One table row per estimator on one simulated sequence, and the conditions to print with them."""
    out = args.out / run_name(sequence, seed, args.end)
    folder = simulated(sequence, seed, args.end, args.out / "data")
    gt, _ = read_poses(folder / "poses.txt")
    gt_sweep_end = sweep_end_truth(gt, np.loadtxt(folder / "times.txt", dtype=np.float64))
    rows = []
    for key in args.peer_methods:
        label, method, extra, deskew = PEER_RUNS[key]
        if peer is None:
            rows.append(
                {
                    "estimator": label,
                    "ape": None,
                    "rot": None,
                    "loops": None,
                    "time": None,
                    "note": "peer not installed",
                }
            )
            continue
        run = peer_run(peer, method, folder, out.with_name(out.name + f"-peer-{key}.npz"), args.peer_threads, extra)
        mid_sweep, _ = ape(run["poses"], gt)
        t, r = ape(run["poses"], gt_sweep_end if deskew.endswith("sweep end") else gt)
        if deskew.endswith("sweep end"):
            deskew += f"; APE against the truth at sweep end (against mid-sweep: {mid_sweep:.3f} m)"
        loops = None if int(run["closures"]) < 0 else counted(int(run["closures"]), "closure")
        rows.append(
            {
                "estimator": label,
                "ape": t,
                "rot": r,
                "loops": loops,
                "time": float(run["seconds"]),
                "note": f"{counted(int(run['threads']), 'thread')}; {deskew}",
                "peer": key,
            }
        )
    methods = [m for m in PAPER_METHODS if args.methods is None or m[0] in args.methods]
    suffix = "-compare" + (f"-{args.label}" if args.label else "")
    comparison, wall = compared(folder, out.with_name(out.name + suffix), methods, args.cache_dir, args.params)
    first = True
    for label, _, _ in methods:
        run = comparison / "runs" / label
        if not (run / "metrics.json").is_file():
            rows.append(
                {
                    "estimator": f"msa-slam {label}",
                    "ape": None,
                    "rot": None,
                    "loops": None,
                    "time": None,
                    "note": "failed: see " + str(run / "error.txt"),
                }
            )
            continue
        m = from_json(json.loads((run / "metrics.json").read_text()), str(run / "metrics.json"))
        front = sum(m.timing.frontend_s.values())
        if first:  # the odometry every msa-slam method shares
            t, r = ape(read_poses(run / "trajectories" / "odometry.kitti")[0], gt)
            replayed = m.timing.frontend_cached.get("odometry")
            cached = " (replayed from the cache: time when computed)" if replayed else ""
            threads = counted(m.setup.odometry_threads, "thread")
            rows.append(
                {
                    "estimator": "msa-slam odometry (KISS-ICP)",
                    "ape": t,
                    "rot": r,
                    "loops": None,
                    "time": m.timing.frontend_s.get("odometry"),
                    "odometry": True,
                    "note": f"{threads}; {deskew_note(m.setup.odometry_config)}{cached}",
                }
            )
            first = False
        t, r = ape(read_poses(run / "trajectories" / "optimised.kitti")[0], gt)
        acc = m.loops.accounting
        recall = fmt(acc.revisit_keyframe_recall, ".2f")
        rows.append(
            {
                "estimator": f"msa-slam {label}",
                "ape": t,
                "rot": r,
                "method": label,
                "recall": number_or_none(acc.revisit_keyframe_recall),
                "false": number_or_none(acc.false_loops),
                "loops": f"{acc.accepted} of {acc.candidates} cand. ({number_or_none(acc.false_loops)} false), "
                f"revisit kf recall {recall}",
                "time": front + m.timing.backend_total,
                "note": f"{m.run.keyframes} keyframes; front end {front:.1f} s + back end "
                f"{m.timing.backend_total:.1f} s",
            }
        )
    conditions = {
        "sequence": f"simulated {trajectory_name(sequence)}",
        "seed": seed,
        "frames": len(gt),
        "compare_wall_s": wall,
    }
    return rows, conditions


def verdicts(rows: list[dict], conditions: dict) -> dict:
    """What the loop goals ask of one sequence and seed: MSA's APE at most KISS-SLAM's (with the per-point times),
    MSA's revisit keyframe recall at least 80 % of all samples', no false loop in any method, no method worse
    than the odometry (None where a row is missing or a recall undefined)."""
    by_method = {r["method"]: r for r in rows if r.get("method")}
    peer = next((r for r in rows if r.get("peer") == "slam"), None)
    odometry = next((r for r in rows if r.get("odometry")), None)
    msa, every = by_method.get("msa"), by_method.get("all")

    def known(*values):
        return all(v is not None for v in values)

    return {
        "sequence": conditions["sequence"],
        "seed": conditions["seed"],
        "msa_ape": msa and msa["ape"],
        "peer_ape": peer and peer["ape"],
        "msa_le_peer": msa["ape"] <= peer["ape"] if msa and peer and known(msa["ape"], peer["ape"]) else None,
        "recall_ratio": (
            msa["recall"] / every["recall"]
            if msa and every and known(msa["recall"], every["recall"]) and every["recall"] > 0
            else None
        ),
        "false_loops": sum(r["false"] or 0 for r in by_method.values()) if by_method else None,
        "worse_than_odometry": (
            [m for m, r in by_method.items() if known(r["ape"]) and r["ape"] > odometry["ape"]] if odometry else None
        ),
    }


def verdict_table(results: list[dict]) -> str:
    """One line per sequence and seed: the goals' figures and whether each holds."""

    def yes(value) -> str:
        return "n/a" if value is None else ("yes" if value else "no")

    lines = [
        "| sequence | seed | MSA APE [m] | KISS-SLAM APE [m] | MSA <= KISS-SLAM | MSA / all revisit kf recall "
        "| false loops (all methods) | worse than odometry |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for v in results:
        ratio, worse = v["recall_ratio"], v["worse_than_odometry"]
        ratio_text = fmt(ratio, ".2f") + ("" if ratio is None else " (>= 0.8)" if ratio >= 0.8 else " (< 0.8)")
        worse_text = "n/a" if worse is None else ", ".join(worse) or "none"
        lines.append(
            f"| {v['sequence']} | {v['seed']} | {fmt(v['msa_ape'])} | {fmt(v['peer_ape'])} "
            f"| {yes(v['msa_le_peer'])} | {ratio_text} | {fmt(v['false_loops'], 'd')} | {worse_text} |"
        )
    return "\n".join(lines) + "\n"


def table(rows: list[dict], conditions: dict) -> str:
    wall = conditions["compare_wall_s"]
    lines = [
        f"### {conditions['sequence']}, world seed {conditions['seed']}, {conditions['frames']} frames"
        + ("" if wall is None else f" (msa-slam compare: {wall:.0f} s wall)"),
        "",
        "| estimator | APE t RMSE [m] | APE rot RMSE [deg] | loops | time [s] | conditions |",
        "|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['estimator']} | {fmt(r['ape'])} | {fmt(r['rot'])} | {r['loops'] or ''} | {fmt(r['time'], '.1f')} "
        f"| {r['note']} |"
        for r in rows
    ]
    return "\n".join(lines) + "\n"


def speed_table(sequence: str, seed: int, args: argparse.Namespace, peer: str | None) -> str:
    """--speed: wall time, CPU time and peak RSS of KISS-SLAM, `msa-slam run` and `msa-slam compare` on one
    simulated sequence, cold, medians of --speed-repeats alternating runs, with each job's APE and the goals'
    ratios (run <= KISS-SLAM, compare <= 1.5x KISS-SLAM in wall time)."""
    folder = simulated(sequence, seed, args.end, args.out / "data")
    gt, _ = read_poses(folder / "poses.txt")
    root = args.out / (run_name(sequence, seed, args.end) + "-speed")
    timings = timed_jobs(folder, root, CLI, peer, DRIVER, args.peer_threads, args.speed_repeats, args.speed_jobs)
    last = root / "last"
    accuracy = {
        "msa-slam run --sampler msa": last / "run" / "trajectories" / "optimised.kitti",
        "msa-slam compare (7 methods)": last / "compare" / "runs" / "msa" / "trajectories" / "optimised.kitti",
    }
    lines = [
        f"### Speed: simulated {trajectory_name(sequence)}, world seed {seed}, {len(gt)} frames, cold cache, "
        f"median of {args.speed_repeats} runs",
        "",
        "| job | wall [s] | CPU [s] | peak RSS [MiB] | wall / KISS-SLAM's | APE t RMSE [m] | runs' wall [s] |",
        "|---|---|---|---|---|---|---|",
    ]
    peer_wall = median_timing(timings["KISS-SLAM"]).wall_s if "KISS-SLAM" in timings else None
    for name, runs in timings.items():
        median = median_timing(runs)
        if name == "KISS-SLAM":
            with np.load(last / "peer.npz") as data:
                error = ape(data["poses"], sweep_end_truth(gt, np.loadtxt(folder / "times.txt")))[0]
        else:
            error = ape(read_poses(accuracy[name])[0], gt)[0]
        ratio = None if peer_wall is None else median.wall_s / peer_wall
        lines.append(
            f"| {name} | {median.wall_s:.1f} | {median.cpu_s:.1f} | {median.peak_rss_mib:.0f} "
            f"| {fmt(ratio, '.2f')} | {error:.3f} | {', '.join(f'{t.wall_s:.1f}' for t in runs)} |"
        )
    threads = "all cores" if args.peer_threads == 0 else counted(args.peer_threads, "thread")
    lines += [
        "",
        f"KISS-SLAM: KISS-ICP on {threads}, deskew to sweep end (APE against the truth at sweep end). "
        "msa-slam: its defaults (odometry on one thread, deskew to mid-sweep; compare's methods in one worker "
        "process per CPU); compare's APE is MSA's. Goals: run <= 1.00, compare <= 1.50 of KISS-SLAM's wall.",
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", default="07", help="KITTI trajectories to simulate, e.g. 07,09")
    parser.add_argument("--seeds", default="0", help="world seeds, e.g. 0,1")
    parser.add_argument("--end", type=int, default=None, help="first N frames of each trajectory only")
    parser.add_argument(
        "--methods", default=None, help="msa-slam methods (compare's labels, e.g. msa,constant-2m; default: all seven)"
    )
    parser.add_argument(
        "--peer-python",
        default=os.environ.get("MSA_SLAM_PEER_PYTHON", sys.executable),
        help="Python with kiss-slam installed (default: $MSA_SLAM_PEER_PYTHON, else this one)",
    )
    parser.add_argument("--peer-threads", type=int, default=1, help="KISS-ICP threads of the peer (0: all cores)")
    parser.add_argument(
        "--peer-methods",
        default=",".join(PEER_RUNS),
        help="the peer's runs: icp (KISS-ICP alone, KISS-SLAM's odometry settings), slam (KISS-SLAM "
        "with the per-point times), slam-raw (KISS-SLAM without them, as its CLI reads .bin)",
    )
    parser.add_argument(
        "-p",
        "--param",
        dest="params",
        action="append",
        default=[],
        help="msa-slam run configuration override KEY=VALUE, as the commands' -p (repeatable)",
    )
    parser.add_argument("--label", default=None, help="name of a run with -p overrides (kept apart from the default)")
    parser.add_argument("--out", type=Path, default=Path("msa_slam_results/bench_peer"))
    parser.add_argument("--cache-dir", type=Path, default=None, help="msa-slam's cache (default: --out/cache)")
    parser.add_argument(
        "--speed",
        action="store_true",
        help="instead of the accuracy tables: time KISS-SLAM, `msa-slam run` and `msa-slam compare` "
        "end to end from a cold cache (wall, CPU, peak RSS)",
    )
    parser.add_argument("--speed-repeats", type=int, default=3, help="--speed: runs of each job (medians)")
    parser.add_argument(
        "--speed-jobs", default=",".join(JOBS), help=f"--speed: the jobs to time, of {', '.join(JOBS)} (default: all)"
    )
    args = parser.parse_args()
    args.methods = None if args.methods is None else args.methods.split(",")
    if args.params and not args.label:
        parser.error("-p overrides need a --label (their comparisons are kept under it, apart from the default's)")
    known = [label for label, _, _ in PAPER_METHODS]
    if args.methods is not None and not set(args.methods) <= set(known):
        parser.error(f"--methods: choose from {', '.join(known)}")
    args.peer_methods = args.peer_methods.split(",")
    args.speed_jobs = tuple(args.speed_jobs.split(","))
    if not set(args.speed_jobs) <= set(JOBS):
        parser.error(f"--speed-jobs: choose from {', '.join(JOBS)}")
    if not set(args.peer_methods) <= set(PEER_RUNS):
        parser.error(f"--peer-methods: choose from {', '.join(PEER_RUNS)}")
    args.cache_dir = args.cache_dir or args.out / "cache"
    args.out.mkdir(parents=True, exist_ok=True)
    missing = peer_missing(args.peer_python)
    if missing is not None:
        print(INSTALL.format(python=args.peer_python, error=missing), file=sys.stderr)
    peer = None if missing is not None else args.peer_python
    date = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    text = [
        f"bench_peer, {date}, {cpu_model()} ({os.cpu_count()} CPUs). APE: evo, {ATE_ALIGNMENT} fitted on "
        "every frame, RMSE over every frame against the simulator's ground truth. msa-slam: compare --mode "
        "realistic --no-sweep (full-rate trajectory; loops: accepted of candidates, false = pose off "
        "ground truth by > 3 m or 5 deg, revisit keyframe recall); time = front end + back end.",
        "",
    ]
    print(text[0] + "\n", flush=True)
    if args.params:
        text[0] += f" Overrides ({args.label}): " + " ".join(f"-p {p}" for p in args.params) + "."
    if args.speed:
        text = [text[0], ""]
        for sequence in args.sequences.split(","):
            for seed in (int(s) for s in args.seeds.split(",")):
                text.append(speed_table(sequence.strip(), seed, args, peer))
                print(text[-1], flush=True)
        (args.out / "table-speed.md").write_text("\n".join(text))
        return
    goals = []
    for sequence in args.sequences.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            rows, conditions = rows_for(sequence.strip(), seed, args, peer)
            goals.append(verdicts(rows, conditions))
            text.append(table(rows, conditions))
            print(text[-1], flush=True)
    text.append("### Loop goals per sequence and seed\n\n" + verdict_table(goals))
    print(text[-1], flush=True)
    (args.out / ("table.md" if not args.label else f"table-{args.label}.md")).write_text("\n".join(text))


if __name__ == "__main__":
    main()
