"""What a run leaves behind: its result folder (config, metrics.json, CSV tables, trajectories, figures) and
report.md, written as the run ends and rewritten later from the files alone (`msa-slam report`)."""

from msa_slam._lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(["write_run", "write_run_files"], "results"),
    "report_markdown": "report",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
