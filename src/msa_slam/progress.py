"""The pipeline's one progress helper: a rich bar on a terminal, plain log lines elsewhere (a cluster job's log
gets a start line, a line every ~10 % and a finish line with the stage's time); `quiet` turns both off."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from typing import Any, TextIO

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn, TimeElapsedColumn

STEP = 0.1  # a log line every 10 % of a stage...
MIN_INTERVAL_S = 1.0  # ...but not within a second of the previous one (a short stage logs start and finish)


def progress_bar(quiet: bool = False, transient: bool = True, fields: str = "") -> Progress | LogProgress:
    """Progress of long stages: a rich bar (description, bar, count, `fields` as a format of the tasks'
    fields, elapsed time) on a terminal, LogProgress lines on stderr otherwise, nothing when `quiet`."""
    if not quiet and not Console().is_terminal:
        return LogProgress(fields=fields)
    extra = [TextColumn(fields)] if fields else []
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        *extra,
        TimeElapsedColumn(),
        disable=quiet,
        transient=transient,
    )


@dataclass
class _Task:
    description: str
    total: float | None
    fields: dict[str, Any]
    start: float = field(default_factory=time.monotonic)
    completed: float = 0.0
    logged_step: int = 0
    logged_at: float = field(default_factory=time.monotonic)
    finished: bool = False


class LogProgress:
    """The subset of rich.progress.Progress the pipeline uses (add_task, advance, update, context manager),
    written as log lines: `<stage>: start (N)`, `<stage>: k/N (p %), t s` every ~10 % (at most one per
    `min_interval_s`), `<stage>: done k/N in t s`."""

    def __init__(self, stream: TextIO | None = None, fields: str = "", min_interval_s: float = MIN_INTERVAL_S) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.fields = fields
        self.min_interval_s = min_interval_s
        self._tasks: list[_Task] = []

    def __enter__(self) -> LogProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        for task in self._tasks:
            if not task.finished:
                self._finish(task, "stopped at")

    def add_task(self, description: str, total: float | None = None, **fields: Any) -> TaskID:
        self._tasks.append(_Task(description, total, dict(fields)))
        self._log(f"{description}: start" + (f" ({total:g})" if total is not None else ""))
        return TaskID(len(self._tasks) - 1)

    def advance(self, task_id: TaskID, advance: float = 1) -> None:
        self.update(task_id, advance=advance)

    def update(
        self,
        task_id: TaskID,
        *,
        completed: float | None = None,
        advance: float | None = None,
        description: str | None = None,
        total: float | None = None,
        **fields: Any,
    ) -> None:
        task = self._tasks[task_id]
        if description is not None:
            task.description = description
        if total is not None:
            task.total = total
        task.fields.update(fields)
        if completed is not None:
            task.completed = completed
        if advance is not None:
            task.completed += advance
        if task.finished or not task.total:
            return
        if task.completed >= task.total:
            self._finish(task, "done")
            return
        step = int(task.completed / task.total / STEP)
        if step > task.logged_step and time.monotonic() - task.logged_at >= self.min_interval_s:
            task.logged_step, task.logged_at = step, time.monotonic()
            self._log(
                f"{task.description}: {self._count(task)} ({100 * task.completed / task.total:.0f} %), "
                f"{time.monotonic() - task.start:.1f} s{self._fields(task)}"
            )

    def _finish(self, task: _Task, word: str) -> None:
        task.finished = True
        self._log(
            f"{task.description}: {word} {self._count(task)} in {time.monotonic() - task.start:.1f} s"
            f"{self._fields(task)}"
        )

    @staticmethod
    def _count(task: _Task) -> str:
        return f"{task.completed:g}/{task.total:g}" if task.total is not None else f"{task.completed:g}"

    def _fields(self, task: _Task) -> str:
        """`fields` formatted for a line; nothing when they are empty (no trailing comma)."""
        text = self.fields.format(task=task).strip() if self.fields else ""
        return f", {text}" if text else ""

    def _log(self, line: str) -> None:
        print(line, file=self.stream, flush=True)
