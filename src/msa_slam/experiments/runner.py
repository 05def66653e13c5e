"""Run the cells of a grid in this process, in local worker processes, or on a Dask cluster, resumably.

The output folder (layout: msa_slam.experiments.folder) is checked and locked before any work
(msa_slam.io.outputs): a folder msa-slam did not write is refused, a previous experiment folder is resumed
(its finished cells of the current grid are skipped, unless their data or code changed since they ran:
msa_slam.experiments.identity), and a second run on the same folder refuses while the first holds the lock.
Each cell folder is written under a temporary name and moved into place when complete, so a crash or kill never
leaves a half cell that looks finished.

With `--scheduler tcp://host:port` the workers write into the same folder, so it must be on a file
system they share (the usual NFS/cluster set-up).
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
import traceback
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from msa_slam.errors import InputError
from msa_slam.evaluation.run_metrics import RunMetrics
from msa_slam.experiments.cell_info import CellRecord
from msa_slam.experiments.estimate import GridClock, GridEstimate, estimate_grid
from msa_slam.experiments.folder import CELL_FILE, KIND, cell_dir, finished_cells, read_cell, stale_cells, write_grid
from msa_slam.experiments.grid import Cell, GridSpec, check_datasets, expand, run_key
from msa_slam.experiments.identity import cell_identities, outdated_cells
from msa_slam.experiments.inputs import Preparation, input_groups, prepare_inputs
from msa_slam.experiments.sharing import SharePlan, copy_cell, finished_runs, plan_sharing
from msa_slam.io.atomic import write_text_atomic
from msa_slam.io.marker import foreign_in_units
from msa_slam.io.outputs import DEFAULT_RESULTS, open_result_folder, some_names, staged_dir
from msa_slam.io.staging import remove_abandoned, unmark_finished
from msa_slam.io.write_errors import OutputError
from msa_slam.workers import check_workers

DEFAULT_PARENT = DEFAULT_RESULTS / "experiments"
log = logging.getLogger(__name__)
STORES = "stores"  # out/stores/<cell>: the keyframe clouds of online cells with cloud_store=disk


def is_finished(out: str | os.PathLike, cell: Cell) -> bool:
    """True when the cell's folder is complete and readable (it only appears, by rename, once written)."""
    return read_cell(cell_dir(out, cell.id)) is not None


def clean_partials(out: str | os.PathLike) -> list[Path]:
    """Remove what cells interrupted by a crash or kill left: their staging folders and on-disk keyframe
    stores, only those proven msa-slam's whose writer is gone (io.staging.abandoned, disk_store's own rule),
    and the store folders then left empty; anything else stays. Return what was removed."""
    from msa_slam.registration.disk_store import remove_stale_stores  # loads small_gicp

    cells, stores = Path(out) / "cells", Path(out) / STORES
    removed = []
    if cells.is_dir():
        removed += remove_abandoned(sorted(list(cells.glob(".*.partial-*")) + list(cells.glob(".*.old-*"))))
        for cell in cells.iterdir():
            unmark_finished(cell)
    if stores.is_dir() and not stores.is_symlink():
        for folder in sorted(stores.iterdir()):
            if folder.is_dir() and not folder.is_symlink():
                removed += remove_stale_stores(folder)
                removed += _remove_empty_folder(folder)
        removed += _remove_empty_folder(stores)
    return removed


def check_replaceable(out: Path, cell_ids: list[str]) -> None:
    """Before a cell folder that exists is rerun (its data or code changed, or its files are damaged) and so
    replaced: refuse, in one line, when it holds files the result marker does not list as msa-slam's (a
    person's notes in a cell are not msa-slam's to remove; marker.foreign_in_units). msa-slam's own files there,
    damaged or changed, are what the rerun replaces."""
    found = foreign_in_units(out, [f"cells/{cell_id}" for cell_id in cell_ids])
    for cell_id in cell_ids:
        if found[f"cells/{cell_id}"]:
            raise OutputError(
                f"--out {out}: cell {cell_id} must be rerun, but its folder holds files msa-slam did not "
                f"write ({some_names(found[f'cells/{cell_id}'])}); move them elsewhere or choose "
                "another --out"
            )


def _remove_empty_folder(path: Path) -> list[Path]:
    """[path] when it was an empty folder, now removed; [] when it holds anything."""
    try:
        path.rmdir()
    except OSError:
        return []
    return [path]


def run_cell(info: CellRecord, config: dict[str, Any], out: str, figures: bool = False) -> RunMetrics:
    """Run one cell and write its folder atomically; returns its metrics (a top-level function so Dask and
    process pools can ship it)."""
    from msa_slam.experiments.sweep import threshold_sweep
    from msa_slam.io.tables import write_json
    from msa_slam.pipeline.config import RunConfig, make_config, make_online_config
    from msa_slam.pipeline.driver import run
    from msa_slam.pipeline.live import with_odometry_threads
    from msa_slam.reporting.results import write_run_files

    online = info.pipeline == "online"
    cfg: RunConfig
    if online:
        cfg = make_online_config(config)
        if cfg.cloud_store == "disk" and cfg.store_dir is None:  # the store removes it again when it closes
            cfg = make_online_config({**config, "store_dir": str(Path(out) / STORES / info.id)})
        cfg = with_odometry_threads(cfg, 1)  # every cell, a live: one too, on one thread: reproducible, a core each
    else:
        cfg = make_config(config)
    result = run(cfg, quiet=True, sweep=None if online else threshold_sweep)
    with staged_dir(cell_dir(out, info.id)) as tmp:
        write_run_files(result, tmp, figures or not online)
        write_json(tmp / CELL_FILE, info.to_json())
    return result.measured


@dataclass
class GridRun:
    """What a run of the grid did: cells finished now, skipped (finished earlier), copied from an identical cell
    (id: the folder copied; experiments.sharing), rerun (finished earlier on other data or code: id: the line
    saying so) and failed (id: reason), and the cell folders of an earlier, different grid left out of the
    report."""

    out: Path
    ran: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    shared: dict[str, str] = field(default_factory=dict)
    rerun: dict[str, str] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)
    stale: list[str] = field(default_factory=list)

    @property
    def report(self) -> Path:
        return self.out / "report.md"


def _record(run: GridRun, cell: Cell, error: BaseException | None) -> None:
    errors = run.out / "errors"
    path = errors / f"{cell.id}.txt"
    if error is None:
        run.ran.append(cell.id)
        path.unlink(missing_ok=True)
        return
    errors.mkdir(exist_ok=True)
    write_text_atomic(path, "".join(traceback.format_exception(type(error), error, error.__traceback__)))
    reason = (str(error).strip().splitlines() or [""])[0]
    run.failed[cell.id] = f"{type(error).__name__}: {reason}"


def run_grid(
    grid: GridSpec,
    out: str | os.PathLike | None,
    scheduler: str | None = None,
    workers: int = 1,
    client=None,
    quiet: bool = True,
    overwrite: bool = False,
    where: str = "grid",
    share_from: Sequence[Path] = (),
) -> GridRun:
    """Run the unfinished cells of `grid` into `out`, then write the aggregate report.

    `out` is checked and locked first (msa_slam.io.outputs): None picks a new timestamped folder under
    msa_slam_results/experiments; a previous experiment folder is resumed, or with `overwrite` replaced.
    In this process when `workers == 1` and no scheduler/client; otherwise through Dask: `client` (any
    distributed.Client, e.g. on a LocalCluster), else the cluster at `scheduler`, else a LocalCluster of
    `workers` single-threaded processes. Bad input (datasets, the scheduler address) is refused before any cell
    runs; `where` (the grid file) starts those messages. Every cell records the identity of its data and code
    (msa_slam.experiments.identity); a finished cell whose data or code changed since is removed and rerun,
    with a warning and a line in report.md. A cell that computes the same run as a finished cell of `out` or of
    the experiment folders `share_from`, or as another cell of this run, is copied instead of run
    (experiments.sharing).
    """
    from msa_slam.experiments.report import write_report

    check_workers(workers)
    cells = expand(grid, where)
    check_datasets(grid, where, cells)
    if scheduler is not None:
        check_scheduler(scheduler)
    with open_result_folder(out, kind=KIND, default_parent=DEFAULT_PARENT, overwrite=overwrite, resume=True) as folder:
        finished = {} if overwrite or not folder.path.is_dir() else finished_cells(folder.path, cells)
        identities = cell_identities(cells)
        folder.prepare_in_place(fresh=overwrite, grows=("cells",), unit_record=CELL_FILE)
        run = GridRun(folder.path, rerun=outdated_cells(finished, identities))
        check_replaceable(run.out, [*run.rerun, *(c.id for c in cells if c.id not in finished)])
        for cell_id, line in run.rerun.items():  # never reported beside cells of the current data and code
            log.warning("experiment: %s", line)
            shutil.rmtree(cell_dir(run.out, cell_id), ignore_errors=True)
            del finished[cell_id]
        (run.out / "cells").mkdir(exist_ok=True)
        write_grid(run.out, grid)
        clean_partials(run.out)
        run.stale = stale_cells(run.out, cells)
        run.skipped = [cell.id for cell in cells if cell.id in finished]
        todo = [cell for cell in cells if cell.id not in finished]
        keys = {cell.id: run_key(cell, identities[cell.id]) for cell in todo}
        infos = {cell.id: CellRecord.of(cell, identities[cell.id], keys[cell.id]) for cell in todo}
        plan = plan_sharing(todo, keys, finished_runs([run.out, *share_from]))
        local = scheduler is None and client is None
        estimate = estimate_grid(
            grid.name, cells, finished, plan.run, workers if local else None, shared=len(plan.copies) + len(plan.after)
        )
        if not quiet:  # before the first cell, on a terminal or not
            print(estimate.line(), file=sys.stderr, flush=True)
        _run_cells(grid, plan.run, run, scheduler, workers, client, quiet, estimate, infos)
        _copy_cells(run, plan, infos)
        write_report(run.out, finished=finished, rerun=list(run.rerun.values()))
        folder.record_files()
    return run


def _copy_cells(run: GridRun, plan: SharePlan, infos: dict[str, CellRecord]) -> None:
    """Write the cells of `plan` that copy a finished cell; one whose cell of this run failed fails with it."""
    sources = {
        **plan.copies,
        **{cid: cell_dir(run.out, first) for cid, first in plan.after.items() if first not in run.failed},
    }
    for cid, first in plan.after.items():
        if first in run.failed:
            run.failed[cid] = f"the same run as cell {first}, which failed: {run.failed[first]}"
            write_text_atomic(run.out / "errors" / f"{cid}.txt", run.failed[cid] + "\n")
    for cid, source in sources.items():
        try:
            copy_cell(source, run.out, infos[cid])
        except OSError as exc:
            run.failed[cid] = f"{type(exc).__name__}: copying the identical cell {source.name}: {exc}"
            continue
        (run.out / "errors" / f"{cid}.txt").unlink(missing_ok=True)
        run.shared[cid] = source.name


def check_scheduler(scheduler: str) -> None:
    """A malformed address is refused before the result folder is made (whether it answers is known later)."""
    from distributed.comm.addressing import get_address_host_port

    try:
        get_address_host_port(scheduler)
    except ValueError as exc:
        raise InputError(f"--scheduler {scheduler!r}: {exc}; give the address as tcp://host:port") from None


def _run_cells(
    grid: GridSpec,
    todo: list[Cell],
    run: GridRun,
    scheduler: str | None,
    workers: int,
    client,
    quiet: bool,
    estimate: GridEstimate,
    infos: dict[str, CellRecord],
) -> None:
    """Run the `todo` cells, each recording `infos` (its info, identity and run key) as its cell.json."""
    from msa_slam.progress import progress_bar

    clock = GridClock(estimate)
    with progress_bar(quiet, transient=False, fields="{task.fields[left]}") as bar:
        task = bar.add_task(f"grid {grid.name} ({len(run.skipped)} done before)", total=len(todo), left=clock.left([]))

        def advance() -> None:
            bar.update(task, advance=1, left=clock.left(run.ran + list(run.failed)))

        if todo and client is None and scheduler is None and workers == 1:
            for group in input_groups(todo):
                bar.update(task, description=f"inputs of {group[0][1]['dataset']} (shared by its cells)")
                _prepare_here(group)
            for cell in todo:
                bar.update(task, description=f"{cell.method} on {cell.dataset}")
                try:
                    run_cell(infos[cell.id], cell.config, str(run.out), grid.figures)
                    _record(run, cell, None)
                except Exception as exc:  # a failing cell must not stop the grid
                    _record(run, cell, exc)
                advance()
        elif todo:
            _run_dask(todo, infos, run.out, grid.figures, scheduler, workers, client, run, advance)


def _prepare_inputs(client, todo: list[Cell]) -> None:
    """Build the inputs the `todo` cells share (experiments.inputs) on the cluster, one task a dataset, before any
    cell is submitted; a failure is logged and left to the cells, which record it."""
    from distributed import as_completed

    groups = input_groups(todo)
    futures = {
        client.submit(prepare_inputs, group, key=f"inputs-{k}-{todo[0].id}", pure=False): group
        for k, group in enumerate(groups)
    }
    for future in as_completed(futures):
        try:
            future.result()
        except Exception as exc:  # the cells meet it again and record it with its traceback
            log.warning("experiment: inputs of %s not prepared ahead: %s", futures[future][0][1]["dataset"], exc)


def _prepare_here(group: list[Preparation]) -> None:
    """Build one dataset's shared inputs in this process before the cells that read them (as _prepare_inputs on a
    cluster); a failure is logged and left to the cells, which record it."""
    try:
        prepare_inputs(group)
    except Exception as exc:  # the cells meet it again and record it with its traceback
        log.warning("experiment: inputs of %s not prepared ahead: %s", group[0][1]["dataset"], exc)


def _run_dask(
    todo: list[Cell],
    infos: dict[str, CellRecord],
    out: Path,
    figures: bool,
    scheduler: str | None,
    workers: int,
    client,
    run: GridRun,
    advance,
) -> None:
    from distributed import Client, LocalCluster, as_completed

    own_cluster = own_client = None
    try:
        if client is None:
            if scheduler is not None:
                try:
                    client = own_client = Client(scheduler, timeout="15s")
                except OSError as exc:
                    raise InputError(f"Dask scheduler {scheduler!r}: cannot connect ({exc})") from None
            else:
                own_cluster = LocalCluster(
                    n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0"
                )
                client = own_client = Client(own_cluster)
        _prepare_inputs(client, todo)
        futures = {
            client.submit(
                run_cell, infos[c.id], c.config, str(out.resolve()), figures, key=f"cell-{c.id}", pure=False
            ): c
            for c in todo
        }
        for future in as_completed(futures):
            cell = futures[future]
            try:
                future.result()
                _record(run, cell, None)
            except Exception as exc:
                _record(run, cell, exc)
            advance()
    finally:
        if own_client is not None:
            own_client.close()
        if own_cluster is not None:
            own_cluster.close()
