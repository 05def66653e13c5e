"""How a report names the data a run read: the scans chosen (--first, --jump, -n), the sequence as figure titles
give it, and the KITTI segment lengths its RPE covered (run reports, comparisons, the seed spread)."""

from __future__ import annotations

import numpy as np

from msa_slam.datasets.options import SourceOptions
from msa_slam.evaluation import KITTI_LENGTHS_M, segment_errors
from msa_slam.evaluation.full_rate import STEP_FRAMES, path_length
from msa_slam.viz.labels import display_name


def scans_read(source: SourceOptions) -> str:
    """Which scans of the dataset a run read (--first, --jump, -n), with the options that chose them: a
    result on the first 200 scans is not one on the whole sequence, and the frame count alone cannot tell
    a short sequence from a cut one."""
    parts = (
        ([f"from scan {source.first} (--first {source.first})"] if source.first else [])
        + ([f"one scan in {source.jump} (--jump {source.jump})"] if source.jump > 1 else [])
        + ([f"at most {source.frames} scans (-n {source.frames})"] if source.frames is not None else [])
    )
    return ", ".join(parts) or "every scan"


def sequence_title(sequence: str, source: SourceOptions, frames: int) -> str:
    """The sequence as figure titles name it, with the scans read (`frames` of them) when --first, --jump or -n
    chose part of it: a figure of 200 scans must not pass for one of the whole recording."""
    name = display_name(sequence)
    if (source.first, source.jump, source.frames) == (0, 1, None):
        return name
    first, jump = source.first, source.jump
    last = first + jump * (frames - 1)
    return f"{name}, scans {first}-{last}" if jump == 1 else f"{name}, scans {first}, {first + jump}, ... {last}"


def rpe_segments(gt: np.ndarray | None) -> tuple[str, str]:
    """KITTI's segment lengths the full-rate RPE averaged over, as a table header's span ("100-400 m") and a
    sentence. Only lengths with a segment along the ground-truth path count (evaluation.full_rate.distance_rpe),
    so a 400 m run must not claim the protocol's 100-800 m."""
    if gt is None or not np.isfinite(gt).all():
        return "KITTI segments", "RPE over KITTI's segments: n/a without a ground-truth pose for every frame"
    lengths = [length for length in KITTI_LENGTHS_M if len(segment_errors(gt, gt, length, STEP_FRAMES)[0])]
    total, longest = float(path_length(gt)[-1]), KITTI_LENGTHS_M[-1]
    if not lengths:
        return "KITTI segments", (
            f"RPE over KITTI's segments: n/a: the trajectory of {total:.1f} m is shorter "
            f"than the segment lengths ({KITTI_LENGTHS_M[0]:g}-{longest:g} m)"
        )
    span = f"{lengths[0]:g}-{lengths[-1]:g} m" if len(lengths) > 1 else f"{lengths[0]:g} m"
    if len(lengths) == len(KITTI_LENGTHS_M):
        return span, f"RPE over KITTI's {span} segments"
    return span, (
        f"RPE over KITTI's segments of {', '.join(f'{x:g}' for x in lengths)} m only (the trajectory "
        f"of {total:.1f} m is too short for the longer ones, up to {longest:g} m)"
    )
