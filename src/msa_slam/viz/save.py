"""Save a matplotlib figure as PNG atomically (so a half-written image never looks complete)."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from msa_slam.io.atomic import atomic_path


def save_figure(fig: Figure, path: str | Path) -> Path:
    """Write `fig` to `path` as PNG via a temporary file; return the path."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return Path(path)
