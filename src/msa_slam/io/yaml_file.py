"""YAML files read with one-line errors (config files, experiment grids)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from msa_slam.errors import InputError


def read_yaml(path: Path) -> Any:
    """The YAML document in `path` (OSError to the caller). A file that is not UTF-8 text or not valid YAML is
    one InputError line naming the file, the line and column and the problem: PyYAML's own message spans up
    to 7 lines with the offending text quoted, which a one-line error of the CLI cannot hold."""
    try:
        return yaml.safe_load(path.read_text())
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = exc.problem or exc.context
        context = ""
        if exc.problem and exc.context:
            start = exc.context_mark
            context = (
                f" ({exc.context}"
                + (
                    f" started at line {start.line + 1}, column {start.column + 1}"
                    if start and start is not mark
                    else ""
                )
                + ")"
            )
        raise InputError(f"{path}: not valid YAML{where}: {problem}{context}") from None
    except yaml.YAMLError as exc:  # e.g. a control character: no line and column, only a position
        raise InputError(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from None
