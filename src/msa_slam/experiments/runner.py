"""Run the cells of a grid in this process, in local worker processes, or on a Dask cluster, resumably.

Output folder layout:
    grid.yaml                 the grid as run
    cells/<cell id>/          one finished run folder per cell (metrics.json, cell.json, ...), written
                              under a temporary name and renamed when complete, so a crash or kill never
                              leaves a half cell that looks finished; a re-run skips the finished ones
    errors/<cell id>.txt      the traceback of a cell that failed (retried on the next run)
    results.csv, results.md, figures/, report.md    the aggregate (msa_slam.experiments.report)

With `--scheduler tcp://host:port` the workers write into the same folder, so it must be on a file
system they share (the usual NFS/cluster set-up).
"""

from __future__ import annotations

import os
import shutil
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from msa_slam.errors import InputError
from msa_slam.experiments.grid import Cell, GridSpec, expand

CELL_FILE = "cell.json"


def cell_dir(out: Path, cell: Cell) -> Path:
    return Path(out) / "cells" / cell.id


def is_finished(out: Path, cell: Cell) -> bool:
    """True when the cell's folder is complete (it only appears, by rename, once everything is written)."""
    folder = cell_dir(out, cell)
    return (folder / "metrics.json").is_file() and (folder / CELL_FILE).is_file()


def clean_partials(out: Path) -> list[Path]:
    """Remove temporary folders of cells interrupted by a crash or kill (and their on-disk keyframe stores);
    return what was removed."""
    cells = Path(out) / "cells"
    stale = [p for p in cells.glob(".*.partial-*")] if cells.is_dir() else []
    stale += [Path(out) / "stores"] if (Path(out) / "stores").is_dir() else []
    for path in stale:
        shutil.rmtree(path, ignore_errors=True)
    return stale


def run_cell(info: dict[str, Any], config: dict[str, Any], out: str, figures: bool = False) -> dict[str, Any]:
    """Run one cell and write its folder atomically; returns its metrics (a top-level function so Dask and
    process pools can ship it)."""
    from msa_slam.pipeline.results import atomic_dir, write_json

    target = Path(out) / "cells" / info["id"]
    if info["pipeline"] == "online":
        from msa_slam.pipeline.online import run_online
        from msa_slam.pipeline.online_config import make_online_config
        from msa_slam.pipeline.online_results import write_online_files

        cfg = make_online_config(config)
        if cfg.cloud_store == "disk" and cfg.store_dir is None:
            cfg = make_online_config({**config, "store_dir": str(Path(out) / "stores" / info["id"])})
        result = run_online(cfg, quiet=True)
        with atomic_dir(target) as tmp:
            write_online_files(result, tmp, figures)
            write_json(tmp / CELL_FILE, info)
        if cfg.store_dir and Path(out) in Path(cfg.store_dir).parents:
            shutil.rmtree(cfg.store_dir, ignore_errors=True)
    else:
        from msa_slam.pipeline.batch import run_batch
        from msa_slam.pipeline.config import make_config
        from msa_slam.pipeline.results import write_run_files

        result = run_batch(make_config(config), quiet=True)
        with atomic_dir(target) as tmp:
            write_run_files(result, tmp)
            write_json(tmp / CELL_FILE, info)
    return result.metrics


@dataclass
class GridRun:
    """What a run of the grid did: cells finished now, skipped (finished earlier) and failed."""

    out: Path
    ran: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)


def _record(run: GridRun, cell: Cell, error: BaseException | None) -> None:
    errors = run.out / "errors"
    path = errors / f"{cell.id}.txt"
    if error is None:
        run.ran.append(cell.id)
        path.unlink(missing_ok=True)
        return
    errors.mkdir(exist_ok=True)
    text = "".join(traceback.format_exception(type(error), error, error.__traceback__))
    path.write_text(text)
    run.failed[cell.id] = f"{type(error).__name__}: {error}"


def run_grid(grid: GridSpec, out: str | os.PathLike, scheduler: str | None = None, workers: int = 1,
             client=None, quiet: bool = True) -> GridRun:
    """Run the unfinished cells of `grid` into `out`, then write the aggregate report.

    In this process when `workers == 1` and no scheduler/client; otherwise through Dask: `client` (any
    distributed.Client, e.g. on a LocalCluster), else the cluster at `scheduler`, else a LocalCluster of
    `workers` single-threaded processes.
    """
    from msa_slam.experiments.report import write_report
    from msa_slam.progress import progress_bar

    if workers < 1:
        raise InputError(f"--workers must be >= 1, got {workers}")
    out = Path(out)
    (out / "cells").mkdir(parents=True, exist_ok=True)
    (out / "grid.yaml").write_text(yaml.safe_dump(grid.model_dump(mode="json"), sort_keys=False))
    clean_partials(out)
    cells = expand(grid)
    run = GridRun(out)
    todo = []
    for cell in cells:
        if is_finished(out, cell):
            run.skipped.append(cell.id)
        else:
            todo.append(cell)
    with progress_bar(quiet, transient=False) as bar:
        task = bar.add_task(f"grid {grid.name} ({len(run.skipped)} done before)", total=len(todo))
        if todo and client is None and scheduler is None and workers == 1:
            for cell in todo:
                bar.update(task, description=f"{cell.method} on {cell.dataset}")
                try:
                    run_cell(cell.info(), cell.config, str(out), grid.figures)
                    _record(run, cell, None)
                except Exception as exc:  # a failing cell must not stop the grid
                    _record(run, cell, exc)
                bar.advance(task)
        elif todo:
            _run_dask(todo, out, grid.figures, scheduler, workers, client, run, lambda: bar.advance(task))
    write_report(out)
    return run


def _run_dask(todo: list[Cell], out: Path, figures: bool, scheduler: str | None, workers: int, client,
              run: GridRun, advance) -> None:
    from distributed import Client, LocalCluster, as_completed

    own_cluster = own_client = None
    try:
        if client is None:
            if scheduler is not None:
                client = own_client = Client(scheduler, timeout="15s")
            else:
                own_cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                           dashboard_address=":0")
                client = own_client = Client(own_cluster)
        futures = {client.submit(run_cell, c.info(), c.config, str(out.resolve()), figures, key=f"cell-{c.id}",
                                 pure=False): c for c in todo}
        for future in as_completed(futures):
            cell = futures[future]
            try:
                future.result()
                _record(run, cell, None)
            except Exception as exc:
                _record(run, cell, exc)
            advance()
    except OSError as exc:
        raise InputError(f"Dask scheduler {scheduler!r}: cannot connect ({exc})") from None
    finally:
        if own_client is not None:
            own_client.close()
        if own_cluster is not None:
            own_cluster.close()
