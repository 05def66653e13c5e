"""One exception type for bad user input, so the CLI can print it as a single clear line; and the one line a
saved traceback ends with, for reports of what failed."""

from pathlib import Path


class InputError(ValueError):
    """Bad user input: the message names the file/frame/parameter and what is wrong."""


def error_line(path: Path) -> str:
    """`Type: message` of the exception a traceback file ends with: its first line after the last traceback's
    (indented) frames; a message's further lines are left out."""
    lines = path.read_text(errors="replace").splitlines()
    start = max((i for i, line in enumerate(lines) if line.startswith("Traceback (")), default=-1) + 1
    line = next((line for line in lines[start:] if line.strip() and not line.startswith(" ")), "an error")
    name, colon, message = line.partition(": ")
    return name.rsplit(".", 1)[-1] + colon + message  # the type without its module, as the run's own lines
