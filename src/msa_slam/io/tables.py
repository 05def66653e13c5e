"""Small writers shared by every result folder: JSON with numpy values, CSV tables of dict rows, MiB text."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any


def _json_default(value: Any) -> Any:
    import numpy as np

    if isinstance(value, (np.integer, np.floating)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def write_json(path: Path, data: Any) -> None:
    """`data` as indented JSON (numpy scalars and arrays as plain numbers and lists)."""
    path.write_text(json.dumps(data, indent=1, default=_json_default) + "\n")


def rows_csv(rows: Iterable[Mapping[str, Any]], columns: Sequence[str]) -> str:
    """A table of dict rows as CSV with the given column order."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns)
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


def mib(n: float) -> str:
    """Bytes as a MiB string for reports."""
    return f"{n / 2**20:.2f} MiB"
