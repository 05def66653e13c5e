"""Progress for non-terminals: a log gets a start line, a line every ~10 % and a finish line
with the stage's time; a terminal keeps the rich bar; quiet prints nothing."""

from __future__ import annotations

import io
import re

from helpers.cli import run_cli
from rich.progress import Progress

from msa_slam.progress import LogProgress, progress_bar


def _run(progress: LogProgress, n: int, **fields) -> list[str]:
    with progress as bar:
        task = bar.add_task("odometry", total=n, **fields)
        for _ in range(n):
            bar.advance(task)
    return progress.stream.getvalue().splitlines()


def test_log_lines_start_every_ten_percent_and_finish_with_time():
    lines = _run(LogProgress(io.StringIO(), min_interval_s=0.0), 200)
    assert lines[0] == "odometry: start (200)"
    steps = [int(m[1]) for m in (re.match(r"odometry: \d+/200 \((\d+) %\), [\d.]+ s$", x) for x in lines[1:-1]) if m]
    assert steps == [10, 20, 30, 40, 50, 60, 70, 80, 90]
    assert re.fullmatch(r"odometry: done 200/200 in [\d.]+ s", lines[-1])


def test_short_stages_log_start_and_finish_only():
    lines = _run(LogProgress(io.StringIO(), min_interval_s=3600.0), 50)
    assert len(lines) == 2 and lines[0].endswith("start (50)") and "done 50/50" in lines[1]


def test_fields_and_description_updates_reach_the_log():
    progress = LogProgress(io.StringIO(), fields="{task.fields[fps]:.1f} fps", min_interval_s=0.0)
    with progress as bar:
        task = bar.add_task("online", total=20, fps=0.0)
        bar.update(task, completed=10, fps=12.5, description="online msa")
        bar.update(task, completed=20, fps=25.0)
    lines = progress.stream.getvalue().splitlines()
    assert lines[1].startswith("online msa: 10/20 (50 %)") and lines[1].endswith(", 12.5 fps")
    assert lines[2].startswith("online msa: done 20/20") and lines[2].endswith(", 25.0 fps")


def test_an_interrupted_stage_says_where_it_stopped():
    progress = LogProgress(io.StringIO())
    try:
        with progress as bar:
            task = bar.add_task("descriptors", total=10)
            bar.advance(task, 3)
            raise KeyboardInterrupt
    except KeyboardInterrupt:
        pass
    assert re.fullmatch(r"descriptors: stopped at 3/10 in [\d.]+ s", progress.stream.getvalue().splitlines()[-1])


def test_progress_bar_picks_log_lines_off_a_terminal_and_nothing_when_quiet(monkeypatch, capsys):
    monkeypatch.setattr("rich.console.Console.is_terminal", property(lambda self: False))
    assert isinstance(progress_bar(), LogProgress)
    quiet = progress_bar(quiet=True)
    with quiet as bar:
        bar.advance(bar.add_task("stage", total=2), 2)
    assert capsys.readouterr().err == ""
    monkeypatch.setattr("rich.console.Console.is_terminal", property(lambda self: True))
    assert isinstance(progress_bar(), Progress)


def test_a_non_tty_run_logs_its_long_stages(tmp_path, sequence, odometry_file):
    """`msa-slam run` with its output in a file (a cluster job's log): the front end's and back-end's log lines."""
    import subprocess

    with open(tmp_path / "log.txt", "w") as log:  # an empty cache: the descriptors are computed
        done = run_cli(
            "run",
            "--dataset",
            str(sequence),
            "--odometry",
            str(odometry_file),
            "--frames",  # which stages log and how does not depend on the sequence's length
            "40",
            "--out",
            str(tmp_path / "out"),
            cache=tmp_path / "cache",
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    text = (tmp_path / "log.txt").read_text()
    assert done.returncode == 0, text
    # the front end's one pass over the scans (odometry from the pose file, descriptors and frame clouds computed)
    for stage in ("odometry and descriptors (scan_context) and clouds", "back-end (msa)"):
        assert f"{stage}: start (" in text, text
        assert re.search(rf"{re.escape(stage)}: done (\d+)/\1 in [\d.]+ s", text), text
    assert "\x1b[" not in text  # no terminal control sequences in a log
