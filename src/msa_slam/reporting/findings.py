"""The few plain lines the demo ends with: what its comparison found per method, read back from the folder it
just wrote (comparison.json), and what one world seed cannot tell."""

from __future__ import annotations

from pathlib import Path

from msa_slam.evaluation import NA, fmt
from msa_slam.evaluation.display import spec_for
from msa_slam.evaluation.run_metrics import RunMetrics
from msa_slam.evaluation.spread import MIN_SEEDS
from msa_slam.reporting.stored import listed_methods

BASELINE = "all"  # memory is given as a share of this method's (every frame a keyframe)
REPRODUCE = "msa-slam reproduce"  # the command that repeats the comparison over world seeds


def findings(folder: Path) -> list[str]:
    """Per method of the comparison in `folder`: keyframes (% of frames), memory (% of all samples'), t. ATE
    improvement, loops and PR-AUC, with the table's decimals; then whether the differences exceed the seed
    spread, which a single world seed cannot say."""
    metrics = listed_methods(folder)
    frames = metrics[0].run.frames
    baseline = next((m.memory.total_mib for m in metrics if m.method == BASELINE), None)
    width = max(len(m.method) for m in metrics)
    lines = [f"What the comparison found ({metrics[0].run.dataset}, {frames} frames):"]
    lines += [f"  {m.method:<{width}}  " + _method_line(m, frames, baseline) for m in metrics]
    lines.append(
        f"Whether these differences are beyond the seed-to-seed spread cannot be told from this run: it "
        f"simulated 1 world seed and the paired test needs at least {MIN_SEEDS}; "
        f"`{REPRODUCE}` repeats the comparison over several seeds and says."
    )
    return lines


def _method_line(m: RunMetrics, frames: int, baseline: float | None) -> str:
    """One method's line, each value with the comparison table's decimals (evaluation.display.spec_for)."""
    memory = NA if not baseline else fmt(100.0 * m.memory.total_mib / baseline, ".1f", " %")
    return (
        f"{m.run.keyframes} keyframes ({fmt(100.0 * m.run.keyframes / frames, '.1f', ' %')} of frames), "
        f"memory {memory} of {BASELINE} samples, t. ATE improvement "
        f"{fmt(m.full_rate.improvement.translation, spec_for('improvement_t_pct'), ' %')}, {m.loops.verified} loops, "
        f"PR-AUC {fmt(m.place_recognition.pr_auc, spec_for('pr_auc'))}"
    )
