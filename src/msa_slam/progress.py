"""One look for the pipeline's progress bars (rich); `quiet` turns them off."""

from __future__ import annotations

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn


def progress_bar(quiet: bool = False, transient: bool = True) -> Progress:
    """A rich Progress with description, bar, count and elapsed time (disabled when `quiet`).

    A transient bar is only drawn on a terminal: in a log it would leave nothing but an empty line.
    """
    hidden = quiet or (transient and not Console().is_terminal)
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    disable=hidden, transient=transient)
