"""How reports print metrics: "n/a" for a missing value (its reason goes next to the table), never "-0.0"."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from msa_slam.evaluation.metrics import Unavailable

NA = "n/a"


def fmt(value: float | Unavailable | None, spec: str = ".3f", unit: str = "") -> str:
    """`value` formatted with `spec` plus `unit`; "n/a" for an unavailable value, None or NaN (the reason goes to
    the notes); a result that rounds to zero unsigned."""
    if value is None or isinstance(value, Unavailable) or (isinstance(value, float) and math.isnan(value)):
        return NA
    text = format(value, spec)
    if text.startswith("-") and not any(c in "123456789" for c in text.split("e")[0]):
        text = text[1:]
    return text + unit


# counted, not measured (as are compare's rejected_<reason> columns)
COUNT_KEYS = (
    "keyframes",
    "candidates",
    "verified",
    "rejected",
    "false_loops",
    "true_candidates",
    "distant_loops",
    "revisits",
)


def spec_for(key: str) -> str:
    """The format spec of a metric by the unit its key ends with (metrics.json keys, compare's columns), so a
    table column never mixes 0.123 and 12.3: % improvements and counts (their means over seeds) 1 decimal;
    MiB and seconds 2 (as `mib` and the stage times); errors (m, deg, RPE in % or deg/100 m) and scores
    (PR-AUC, F1) 3."""
    if "improvement" in key or key in COUNT_KEYS or key.startswith("rejected_"):
        return ".1f"
    if key.endswith(("_mib", "_s")):
        return ".2f"
    return ".3f"


NOTE_LABELS = {
    "ate": "ATE (and its % improvement)",
    "ate_odometry": "ATE of the odometry",
    "ate_optimised": "ATE after optimisation",
    "improvement_translation": "translation ATE improvement",
    "improvement_rotation": "rotation ATE improvement",
    "pr": "PR-AUC / F1-max",
    "full_rate_ate": "full-rate ATE (and its % improvement)",
    "full_rate_ate_optimised": "full-rate ATE after optimisation",
    "full_rate_improvement_translation": "full-rate translation ATE improvement",
    "full_rate_improvement_rotation": "full-rate rotation ATE improvement",
    "rpe_kitti": "RPE over KITTI's 100-800 m segments",
    "rpe_10m": "RPE over 10 m (all pairs)",
    "pr_reference": "PR-AUC / F1-max of the reference example's protocol",
    "loop_truth": "true candidates, false and distant loops and revisit recall",
    "revisit_recall": "revisit recall",
    "threshold_sweep": "threshold sensitivity",
    "sampler_realtime_fraction": "sampler time over the data's duration",
}


def notes(reasons: Mapping[str, str], warnings: Sequence[str]) -> list[str]:
    """One sentence per n/a metric (`reasons`: metric -> why it is unavailable) and per warning of a run."""
    return [f"{NOTE_LABELS.get(key, key)} n/a: {reason}" for key, reason in reasons.items()] + [
        f"warning: {text}" for text in warnings
    ]
