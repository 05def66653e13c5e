"""PR-curve figure (PNG) comparing samplers or descriptors."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from msa_slam.io.atomic import atomic_path  # noqa: E402
from msa_slam.place_recognition.metrics import PRCurve  # noqa: E402


def plot_pr_curves(curves: Mapping[str, PRCurve], path: str | Path, title: str = "Precision-recall") -> Path:
    """Write one PR curve per label (legend shows PR-AUC and F1-max) to `path` as PNG."""
    fig, ax = plt.subplots(figsize=(5, 4), dpi=150)
    try:
        for label, curve in curves.items():
            ax.plot(curve.recall, curve.precision, label=f"{label} (AUC {curve.auc:.3f}, F1max {curve.f1_max:.3f})")
        ax.set(xlabel="Recall", ylabel="Precision", xlim=(0, 1.02), ylim=(0, 1.02), title=title)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower left")
        fig.tight_layout()
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)
    return Path(path)
