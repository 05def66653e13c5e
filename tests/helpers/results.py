"""What of a result folder must be identical between two runs of the same command (no wall-clock figures)."""

from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path
from typing import Any

from msa_slam.io.marker import MARKER

# Keys of measured wall-clock time, memory high-water marks and cache hits: they differ between runs.
VOLATILE_KEY = re.compile(r"time|(^|_)ms(_|$)|rss|fps|latency|cached|realtime|_s$")
# Files that carry those figures as text or pixels (report.md, figures, per-step timings), and provenance.json
# (date, command line, machine).
VOLATILE_FILE = re.compile(
    r"(^|/)(report\.md|provenance\.json|processes\.json|comparison\.md|results\.md|figures/.*|steps\.csv"
    r"|.*\.png|errors/.*)$"
)


def _strip(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _strip(v) for k, v in value.items() if not VOLATILE_KEY.search(k)}
    if isinstance(value, list):
        return [_strip(v) for v in value]
    return value


def _strip_csv(text: str) -> str:
    rows = list(csv.DictReader(io.StringIO(text)))
    if not rows:
        return text
    keep = [c for c in rows[0] if not VOLATILE_KEY.search(c)]
    return json.dumps([[r[c] for c in keep] for r in rows])


def stable_content(folder: Path) -> dict[str, Any]:
    """Every file of `folder` (relative path -> content) minus timings: JSON without timing keys, CSV without
    timing columns, other files as bytes; report.md, figures and per-step timings left out."""
    out: dict[str, Any] = {}
    for path in sorted(Path(folder).rglob("*")):
        rel = path.relative_to(folder).as_posix()
        if not path.is_file() or VOLATILE_FILE.search(rel):
            continue
        if path.name == MARKER:  # the files' digests follow their timings; the list of files does not
            out[rel] = {k: v for k, v in json.loads(path.read_text()).items() if k != "digests"}
        elif path.suffix == ".json":
            out[rel] = _strip(json.loads(path.read_text()))
        elif path.suffix == ".csv":
            out[rel] = _strip_csv(path.read_text())
        else:
            out[rel] = path.read_bytes()
    return out


def differences(a: Any, b: Any, path: str = "") -> list[str]:
    """Leaf paths where two stable contents differ (for readable assertion messages)."""
    if isinstance(a, dict) and isinstance(b, dict):
        keys = sorted(set(a) | set(b))
        return [d for k in keys for d in differences(a.get(k), b.get(k), f"{path}/{k}")]
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in differences(x, y, f"{path}[{i}]")]
    return [] if a == b else [f"{path}: {str(a)[:80]!r} != {str(b)[:80]!r}"]
