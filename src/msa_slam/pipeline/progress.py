"""One look for the pipeline's progress bars (rich); `quiet` turns them off."""

from __future__ import annotations

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn


def progress_bar(quiet: bool = False, transient: bool = True) -> Progress:
    """A rich Progress with description, bar, count and elapsed time (disabled when `quiet`)."""
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    disable=quiet, transient=transient)
