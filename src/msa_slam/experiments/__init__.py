"""Reproducible experiment grids (datasets x descriptors x samplers x parameters x seeds): validation,
resumable runs (local or Dask) and aggregate reports (Table II layout, the paper's figures)."""

from msa_slam.experiments.grid import Cell, GridSpec, SamplerSpec, expand, load_grid, parse_grid
from msa_slam.experiments.report import load_cells, make_rows, table2_markdown, write_report
from msa_slam.experiments.runner import GridRun, clean_partials, is_finished, run_cell, run_grid

__all__ = ["Cell", "GridRun", "GridSpec", "SamplerSpec", "clean_partials", "expand", "is_finished", "load_cells",
           "load_grid", "make_rows", "parse_grid", "run_cell", "run_grid", "table2_markdown", "write_report"]
