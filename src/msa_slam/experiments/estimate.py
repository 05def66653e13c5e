"""What an experiment grid will cost: said before its first cell, and kept up to date while it runs.

Before the first cell, one line gives the cell count (in the grid, finished earlier, to run) and an estimate
of the time with its basis:
- resuming a grid with finished cells: the seconds a frame those cells recorded (the stage times in their
  metrics.json: `time_s` and, batch, `frontend_time_s`) times the frames of each cell to run;
- otherwise: the frames each cell processes times an assumed cost a frame of each of its pipeline stages
  (STAGE_S: this project's 2-core machine on the demo's scans, scaled by the points of a scan), which is
  rough (another machine, other scans or samplers differ).
Either leaves out what a cell spends outside its stages (start-up, evaluation, writing its files), which
dominates only seconds-long cells. As cells finish, the time left is the estimate of the cells not yet run
scaled by what the finished ones took against theirs (so it also learns how many Dask workers share them).
"""

from __future__ import annotations

import time
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

from msa_slam.errors import InputError
from msa_slam.evaluation.metrics import Timing
from msa_slam.experiments.folder import FinishedCells
from msa_slam.experiments.grid import Cell
from msa_slam.sources.spec import spec_kind

# Seconds a frame of each stage on this project's machine (2 cores, one thread a stage) for a scan of
# REFERENCE_POINTS points, from the demo (1101 HDL-64 scans of 64 x 720: simulation 30 s on both cores, KISS-ICP
# 139 s, Scan Context 8 s, seven samplers' back ends 117 s). Simulation and KISS-ICP grow with a scan's points.
REFERENCE_POINTS = 64 * 720
STAGE_S = {"simulation": 0.027, "kiss-icp": 0.126, "descriptor": 0.007, "back end": 0.017}


@dataclass(frozen=True)
class GridEstimate:
    """The cell counts and estimated time of a grid about to run; `cell_s`: the estimated seconds of each cell
    to run (by id, on one worker; the weights of GridClock), `seconds`: the wall time for `workers`."""

    name: str
    total: int
    finished: int
    cell_s: dict[str, float]
    seconds: float | None
    basis: str
    shared: int = 0

    def line(self) -> str:
        """The line printed before the first cell."""
        copied = f", {self.shared} copied from an identical cell" if self.shared else ""
        counts = (
            f"grid {self.name}: {self.total} cells, {self.finished} finished earlier{copied}, {len(self.cell_s)} to run"
        )
        if not self.cell_s:
            return counts
        if self.seconds is None:
            return f"{counts}; no estimate of their time: {self.basis}"
        return f"{counts}; estimated time {duration(self.seconds)} ({self.basis})"


def estimate_grid(
    name: str,
    cells: Sequence[Cell],
    finished: FinishedCells,
    todo: Sequence[Cell],
    workers: int | None,
    shared: int = 0,
    done: set[tuple] | None = None,
) -> GridEstimate:
    """The estimate of running `todo` (of the grid's `cells`; `finished`: the finished cells by id) on
    `workers` local processes (None: a Dask cluster of unknown size, then stated for one worker); `shared` cells
    are copied from identical ones instead (experiments.sharing); `done`: the shared work (simulations, front ends)
    that grids estimated before this one will have done, updated with this grid's."""
    opened: dict[tuple, tuple[int | None, int | None]] = {}  # each dataset is looked at once
    sizes = {cell.id: _size(cell, opened) for cell in todo}
    per_frame, basis = _recorded_cost(finished)
    if per_frame is not None:
        cell_s = {cid: None if frames is None else frames * per_frame for cid, (frames, _) in sizes.items()}
    else:
        cell_s, basis = (
            _assumed_costs(todo, sizes, set() if done is None else done),
            (
                "rough: each cell's frames times an assumed cost a frame of its stages on a 2-core machine like this "
                f"project's: {_stage_costs()}"
            ),
        )
    known = [s for s in cell_s.values() if s is not None]
    if not known:  # no frame count (recordings that cannot be opened yet): the clock weighs the cells alike
        return GridEstimate(
            name,
            len(cells),
            len(finished),
            dict.fromkeys(cell_s, 1.0),
            None,
            f"the frames of {len(cell_s)} cell(s) are not known before they run",
            shared,
        )
    mean = sum(known) / len(known)
    unknown = len(cell_s) - len(known)
    if unknown:
        basis += f"; {unknown} cell(s) of unknown length counted as an average one"
    filled = {cid: mean if s is None else s for cid, s in cell_s.items()}
    used = 1 if workers is None else max(1, min(workers, len(todo)))
    spread = "on one worker" if workers is None else f"on {used} worker{'s' * (used > 1)}"
    return GridEstimate(
        name,
        len(cells),
        len(finished),
        filled,
        sum(filled.values()) / used,
        f"{basis}; {spread}; start-up and writing results not included",
        shared,
    )


def _stage_costs() -> str:
    """STAGE_S for the estimate's basis."""
    scaled = ", ".join(f"{stage} {1e3 * STAGE_S[stage]:g} ms" for stage in ("simulation", "kiss-icp"))
    return (
        f"{scaled} for {REFERENCE_POINTS} points a scan (scaled by a scan's points), "
        f"descriptor {1e3 * STAGE_S['descriptor']:g} ms, back end {1e3 * STAGE_S['back end']:g} ms"
    )


def _recorded_cost(finished: FinishedCells) -> tuple[float | None, str]:
    """(seconds a frame, basis) from the stage times finished cells recorded; (None, "") when none did."""
    seconds = frames = 0.0
    counted = 0
    for metrics in (cell.metrics for cell in finished.values()):
        if metrics.run.frames > 0:
            seconds, frames = seconds + recorded_seconds(metrics.timing), frames + metrics.run.frames
            counted += 1
    if not counted:
        return None, ""
    per_frame = seconds / frames
    return per_frame, (
        f"the stage times {counted} finished cell(s) of this grid recorded (metrics.json time_s), "
        f"{1e3 * per_frame:.3g} ms a frame, times each cell's frames"
    )


def recorded_seconds(timing: Timing) -> float:
    """The seconds a finished cell's stages took: its back-end stages (not their `backend_total`; a stage that did
    not run counts 0) and the batch front end's, less the replayed seconds they count for stages read from the
    cache (what computing them took once, not what the cell spent)."""
    values = [v for k, v in timing.stages.items() if k != "backend_total" and v is not None]
    spent = sum(values) + sum((timing.frontend_s or {}).values())
    return float(spent - sum(timing.replayed_s.values()))


def _assumed_costs(
    todo: Sequence[Cell], sizes: Mapping[str, tuple[int | None, int | None]], shared: set[tuple]
) -> dict[str, float | None]:
    """Each cell's seconds from STAGE_S. Work the cells share is counted once, with the first cell needing it
    (`shared`: what is done already, updated): a sim: dataset is simulated once (then cached), and batch cells
    share the cached odometry and descriptors of their dataset; a live: dataset is simulated by every cell, which
    describes its frames itself and registers them too unless KISS-ICP runs on one thread: that odometry is
    computed once for all the cells on the dataset, over all its frames, simulating them once more
    (pipeline.live.prepare_live_odometry)."""
    costs: dict[str, float | None] = {}
    for cell in todo:
        frames, points = sizes[cell.id]
        if frames is None:
            costs[cell.id] = None
            continue
        config, scale = cell.config, (points or REFERENCE_POINTS) / REFERENCE_POINTS
        dataset = (config["dataset"], config.get("dataset_kind"), repr(config.get("source")))
        seconds = frames * STAGE_S["back end"]
        if spec_kind(config["dataset"]) == "live":
            seconds += frames * STAGE_S["simulation"] * scale
        elif spec_kind(config["dataset"]) == "sim" and config["dataset"] not in shared:
            shared.add(config["dataset"])
            seconds += _simulated_frames(config["dataset"]) * STAGE_S["simulation"] * scale
        front = (
            [("kiss-icp", (config.get("odometry"), repr(config.get("odometry_params"))), scale)]
            if config.get("odometry") == "kiss"
            else []
        )
        front.append(("descriptor", (config["descriptor"], repr(config.get("descriptor_params"))), 1.0))
        for stage, key, factor in front:
            if cell.pipeline == "online" and stage == "kiss-icp" and _replayed_live(config):
                if (dataset, key) not in shared:
                    shared.add((dataset, key))
                    seconds += _live_frames(config["dataset"]) * (STAGE_S["simulation"] + STAGE_S[stage]) * factor
            elif cell.pipeline == "online" or (dataset, key) not in shared:
                shared.add((dataset, key))
                seconds += frames * STAGE_S[stage] * factor
        costs[cell.id] = seconds
    return costs


def _replayed_live(config: Mapping) -> bool:
    """True when an online cell replays its live: dataset's odometry computed once: KISS-ICP on one thread, as
    grid cells run it unless their config names another count (experiments.runner.run_cell)."""
    threads = (config.get("odometry_params") or {}).get("num_threads", 1)
    return spec_kind(config["dataset"]) == "live" and config.get("odometry") == "kiss" and threads == 1


def _live_frames(spec: str) -> int:
    """The frames of a live: dataset, all its laps (what its cached odometry registers)."""
    from msa_slam.sources import parse_spec

    parsed = parse_spec(spec)
    return parsed.simulation.frame_count() * parsed.laps


def _size(cell: Cell, opened: dict[tuple, tuple[int | None, int | None]]) -> tuple[int | None, int | None]:
    """(frames, points a scan) the cell processes; (None, None) when that cannot be told without the long work.
    `opened`: the sizes of the datasets already looked at, by (spec, loader, source options)."""
    config = cell.config
    key = (config["dataset"], config.get("dataset_kind", "auto"), tuple(sorted((config.get("source") or {}).items())))
    if key not in opened:
        opened[key] = _dataset_size(*key)
    frames, points = opened[key]
    if frames is not None and config.get("max_frames"):
        frames = min(frames, config["max_frames"])
    return frames, points


def _dataset_size(spec: str, kind: str, source: tuple) -> tuple[int | None, int | None]:
    """(frames, points a scan) of a dataset as a run selects it: simulated ones from their settings (nothing is
    simulated), recordings by opening them and reading their first scan (as a run does first)."""
    from msa_slam.datasets import SourceOptions
    from msa_slam.datasets.sequences import selected_count
    from msa_slam.sim import get_sensor
    from msa_slam.sources import open_sequence, parse_spec

    options = SourceOptions(**dict(source))
    try:
        parsed = parse_spec(spec)
        config = parsed.config
        if parsed.kind == "live":
            frames = config.frame_count() * parsed.laps
        elif parsed.kind == "sim":
            frames = selected_count(config.frame_count(), options.first, options.jump, options.frames, spec)
        else:
            sequence = open_sequence(parsed, kind, source=options)
            return len(sequence), len(sequence[0].points)
    except (InputError, OSError):  # the cell will say what is wrong when it runs
        return None, None
    sensor = get_sensor(config.sensor, azimuth_steps=config.azimuth_steps)
    return frames, sensor.beams * sensor.azimuth_steps


def _simulated_frames(spec: str) -> int:
    """The scans a sim: dataset casts (all of them, whatever part a run selects)."""
    from msa_slam.sources import parse_spec

    return parse_spec(spec).config.frame_count()


class GridClock:
    """The time left of a running grid: the estimate of the cells not yet run times the wall time the finished
    ones took over their estimate (the first estimate until a cell finishes)."""

    def __init__(self, estimate: GridEstimate) -> None:
        self.estimate = estimate
        self.start = time.monotonic()

    def left(self, done: Collection[str]) -> str:
        """'~N left' after the cells `done` (ids, finished or failed) in this run; '' with no estimate or no
        cell left."""
        weights = self.estimate.cell_s
        spent = sum(weights[cid] for cid in done if cid in weights)
        remaining = sum(s for cid, s in weights.items() if cid not in done)
        if not remaining:
            return ""
        if spent > 0:
            return f"~{duration(remaining * (time.monotonic() - self.start) / spent)} left"
        return "" if self.estimate.seconds is None else f"~{duration(self.estimate.seconds)} left (estimate)"


def duration(seconds: float) -> str:
    """`seconds` for a person: 40 s, 12 min, 3 h 20 min, 2 d 5 h."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    if minutes < 90:
        return f"{minutes} min"
    hours, minutes = divmod(minutes, 60)
    if hours < 48:
        return f"{hours} h {minutes:02d} min"
    return f"{hours // 24} d {hours % 24} h"
