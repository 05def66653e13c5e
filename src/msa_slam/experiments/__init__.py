"""Studies over the pipeline: the method comparison (over world seeds too), the threshold sweep, and
reproducible experiment grids (datasets x descriptors x samplers x parameters x seeds): validation,
resumable runs (local or Dask) and aggregate reports (Table II layout, the paper's figures)."""

from msa_slam._lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(["PAPER_METHODS", "run_compare"], "compare"),
    **dict.fromkeys(["Cell", "GridSpec", "SamplerSpec", "expand", "load_grid", "parse_grid"], "grid"),
    **dict.fromkeys(["make_rows", "table2_markdown", "write_report"], "report"),
    **dict.fromkeys(["load_cells"], "folder"),
    **dict.fromkeys(["GridRun", "clean_partials", "is_finished", "run_cell", "run_grid"], "runner"),
    **dict.fromkeys(["rewrite_folder", "rewrite_report"], "rereport"),
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
