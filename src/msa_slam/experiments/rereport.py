"""`msa-slam report DIR` on any result folder: a study's (experiment, reproduce) is rewritten by its own module;
the folders of `run`, `online` and `compare` (`demo` writes a comparison, `compare --seeds` one per seed and the
spread over them) have every report.md the command wrote (a comparison's, each of its methods', the spread's)
written again from the files in the folder, as the command wrote it, without running anything. Each file is
replaced atomically, and only when it is msa-slam's as it wrote it (or missing): a file someone added or edited is
never replaced. Figures are not redrawn: they need the runs' trajectories and loops as the pipeline held them,
which the folder keeps only in part.

It lives in experiments/, the top of the library's layers, because it must know every folder's layout: the
studies' and a comparison over seeds (experiments/), and a run's and a comparison's reports (reporting/, which
imports nothing above it)."""

from __future__ import annotations

from pathlib import Path

from msa_slam.errors import InputError
from msa_slam.experiments.compare import PAPER_METHODS, write_spread
from msa_slam.experiments.folder import CELL_FILE, grid_cells, stale_cells
from msa_slam.experiments.folder import KIND as EXPERIMENT_KIND
from msa_slam.experiments.report import write_report
from msa_slam.experiments.reproduce import rewrite_reproduce_report
from msa_slam.experiments.runner import DEFAULT_PARENT
from msa_slam.experiments.seed_folder import RECORD, SEEDS, SeedRecord, finished_metrics, left_out_seeds, seed_dir
from msa_slam.io.atomic import write_text_atomic
from msa_slam.io.marker import edited_files, foreign_files, recorded_digests, result_kind, write_marker
from msa_slam.io.outputs import MARKER, OutputError, open_result_folder, some_names
from msa_slam.pipeline.config import make_config
from msa_slam.reporting.comparison import PROCESSES, failed_section, table_row
from msa_slam.reporting.comparison import comparison_report as write_comparison_report
from msa_slam.reporting.report import report_markdown
from msa_slam.reporting.results import folder_files, run_figures
from msa_slam.reporting.stored import (
    comparison_figures,
    failed_methods,
    listed_methods,
    read_comparison,
    read_json,
    read_run,
    read_text,
)

KINDS = ("run", "online", "compare")  # the result kinds (io.marker.result_kind) whose reports this module writes
SPREAD_FILES = ("seeds.md", "seeds.csv", "seeds.json", "report.md")  # what compare --seeds writes at the top


def rewrite_folder(
    folder: Path, reference: str | None = None, expected: str = "a result folder of msa-slam"
) -> tuple[Path, list[str]]:
    """`msa-slam report FOLDER`: the reports of any result folder written again from its files; its report.md
    and, for an experiment, the cells of an earlier grid its aggregates leave out. `reference`: an experiment's
    method the differences compare to; `expected`: what the error names as a result folder.

    The studies' folders (experiment, reproduce) are rewritten by their own modules."""
    kind = result_kind(folder)
    if kind is None:
        outer = next((p for p in Path(folder).absolute().parents if result_kind(p) is not None), None)
        inside = f" (it lies inside the result folder {outer}: report that one)" if outer is not None else ""
        raise InputError(
            f"{folder}: not a msa-slam result folder (no {MARKER} written by msa-slam){inside}; "
            f"expected {expected}; nothing written"
        )
    if kind == EXPERIMENT_KIND:
        return _experiment_report(folder, reference)
    if kind == "reproduce":
        if reference is not None:
            raise InputError(
                f"--reference: only for an experiment's folder; {folder} is a result of "
                "`msa-slam reproduce` (its grids' reference is all samples)"
            )
        return rewrite_reproduce_report(folder), []
    if kind not in KINDS:
        raise InputError(
            f"{folder}: a result of `msa-slam {kind}`, which writes no report.md; expected {expected}; nothing written"
        )
    if reference is not None:
        raise InputError(f"--reference: only for an experiment's folder; {folder} is a result of `msa-slam {kind}`")
    return rewrite_report(folder, kind), []


def _experiment_report(folder: Path, reference: str | None) -> tuple[Path, list[str]]:
    """results.csv, results.md, figures and report.md of an experiment folder, and its stale cells."""
    with open_result_folder(folder, kind=EXPERIMENT_KIND, default_parent=DEFAULT_PARENT, resume=True) as result:
        result.prepare_in_place(grows=("cells",), unit_record=CELL_FILE)
        report = write_report(folder, reference)
        result.record_files()
        stale = stale_cells(folder, grid_cells(folder)[1])
    return report, stale


def rewrite_report(folder: Path, kind: str) -> Path:
    """Write the reports of the result `folder` of `kind` (one of KINDS) again, under the folder's lock (a run
    writing it meanwhile is refused); return its report.md."""
    with open_result_folder(folder, kind, Path(folder).parent, resume=True) as result:
        path = result.path
        foreign, edited = foreign_files(path), edited_files(path)
        try:
            texts = _reports(path, kind, set(foreign))  # a bad metrics.json: InputError naming file and key
        except KeyError as exc:  # a seed record or seeds.json of another msa-slam version, or edited
            raise InputError(
                f"{path}: its records lack {exc} (written by another version of msa-slam?); nothing written"
            ) from None
        spread = kind == "compare" and (path / SEEDS).is_dir()
        names = [*texts, *(SPREAD_FILES if spread else ())]
        kept = sorted({name for name in names if name in foreign or name in edited})
        if kept:
            raise OutputError(
                f"{path}: {some_names(kept)}: added or edited since msa-slam wrote the folder; "
                "`msa-slam report` would replace them: move them elsewhere first"
            )
        recorded = recorded_digests(path)
        for name, text in texts.items():
            write_text_atomic(path / name, text)
        if spread:
            _write_seed_spread(path)
        write_marker(path, kind, exclude=foreign, digests={name: recorded[name] for name in edited})
    return path / "report.md"


def _reports(root: Path, kind: str, foreign: set[str]) -> dict[str, str]:
    """Every report.md of the result `root` but the spread's (relative path -> text); `foreign`: the files
    msa-slam did not write, which no report lists."""
    if kind != "compare":
        return {"report.md": run_report(root, foreign)}
    seeds = root / SEEDS
    comparisons = sorted(p for p in seeds.iterdir() if (p / RECORD).is_file()) if seeds.is_dir() else [root]
    texts = {}
    for folder in comparisons:
        texts[_relative(root, folder / "report.md")] = comparison_report(folder)
        for metrics in listed_methods(folder):
            run = folder / "runs" / metrics.method
            texts[_relative(root, run / "report.md")] = run_report(run, foreign, root)
    return texts


def _relative(root: Path, path: Path) -> str:
    return path.relative_to(root).as_posix()


def run_report(folder: Path, foreign: set[str], root: Path | None = None) -> str:
    """report.md of a run folder (run, online, or a method of a comparison under the result folder `root`),
    from its files; `foreign`: the files msa-slam did not write (relative to `root`), which it does not list."""
    prefix = "" if root is None else _relative(root, folder) + "/"
    files = {name for name in folder_files(folder) if prefix + name not in foreign}
    return report_markdown(read_run(folder), run_figures(folder / "figures"), files)


def comparison_report(folder: Path) -> str:
    """report.md of a comparison folder (compare, demo, or a seed of compare --seeds), from its files."""
    frontend, runs = read_comparison(folder)
    processes = read_json(folder / PROCESSES) if (folder / PROCESSES).is_file() else {}
    text = write_comparison_report(
        frontend,
        runs,
        read_text(folder / "comparison.md"),
        comparison_figures(folder),
        processes.get("workers", 1),
        processes.get("main_peak_rss"),
    )
    text += failed_section(failed_methods(folder, [label for label, _, _ in PAPER_METHODS]))
    return text


def _write_seed_spread(folder: Path) -> None:
    """The spread over the seeds seeds.json names, from each seed's comparison.json and seed.json."""
    seeds = read_json(folder / "seeds.json")["seeds"]
    paths = {seed: seed_dir(folder, seed) / RECORD for seed in seeds}
    records = {seed: SeedRecord.from_json(read_json(path), str(path)) for seed, path in paths.items()}
    rows = {seed: [table_row(m) for m in finished_metrics(seed_dir(folder, seed)) or []] for seed in seeds}
    failed = {
        f"seed {seed}: {name}": error for seed, record in records.items() for name, error in record.failed.items()
    }
    first = records[seeds[0]]
    base = make_config({**next(iter(first.methods.values())), "dataset": first.dataset})
    write_spread(folder, base, rows, failed, left_out_seeds(folder, seeds))
