"""What goes where along the path: stretches laid out from a small catalogue of street designs (as real
suburbs repeat house types, so distant places look alike) and hard stretches where ICP degenerates along
the travel direction (open fields, long plain walls, tunnels, highways between barriers).

The rest of the path is laid out block by block as before; with no shares the plan is empty.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from msa_slam.sim.layout import Style

HARD_KINDS: tuple[str, ...] = ("field", "wall", "tunnel", "highway")
DESIGN = "design"
_LENGTHS = {DESIGN: (150.0, 350.0), "field": (80.0, 200.0), "wall": (100.0, 250.0), "tunnel": (60.0, 150.0),
            "highway": (150.0, 300.0)}
_MEAN_SPECIAL = 200.0
STRAIGHT_TOLERANCE_DEG = 15.0  # heading range within a straight run
MIN_DESIGN_M = 100.0  # shortest designed stretch (a straight run's remainder shorter than this stays regular)
_HEADING_STEP_M = 2.0
STRAIGHT_KINDS = (DESIGN, "wall", "tunnel", "highway")  # laid on straight runs where one is near (fields anywhere)


@dataclass(frozen=True)
class Stretch:
    """Arc-length interval [start, end) of the path with a kind ("design" or a hard kind)."""

    start: float
    end: float
    kind: str
    design: int = -1


@dataclass(frozen=True)
class Design:
    """A street design: identical houses at a fixed pitch on both sides, optional back-row block,
    front-garden trees, low front fence and street lights; `detail_seed` fixes the facade detail."""

    length: float
    depth: float
    height: float
    setback: float
    pitch: float
    refl: float
    back: tuple[float, float, float] | None  # length, depth, height of a block behind each house
    tree_pitch: int                          # a tree every this many houses (0: none)
    fence: float                             # fence height (0: none)
    light_pitch: int                         # a street light every this many houses (0: none)
    detail_seed: int


def make_catalogue(n: int, style: Style, rng: np.random.Generator) -> tuple[Design, ...]:
    """`n` designs within the style's ranges (mid-height blocks, as residential streets)."""
    designs = []
    for _ in range(n):
        lo, hi = style.length
        length = float(rng.uniform(lo + 2.0, (lo + hi) / 2 + 2.0))
        h_lo, h_hi = style.height
        back = None
        if rng.random() < 0.5:
            back = (float(rng.uniform(*style.length)), float(rng.uniform(*style.depth)),
                    float(rng.uniform(h_lo + 4.0, h_hi)))
        designs.append(Design(
            length=length, depth=float(rng.uniform(*style.depth)),
            height=float(rng.uniform(h_lo + 2.0, h_lo + 0.6 * (h_hi - h_lo))),
            setback=float(rng.uniform(*style.setback)), pitch=length + float(rng.uniform(*style.gap)),
            refl=float(rng.uniform(0.35, 0.75)), back=back, tree_pitch=int(rng.integers(0, 3)),
            fence=float(rng.uniform(0.8, 1.6)) if rng.random() < 0.5 else 0.0,
            light_pitch=int(rng.integers(1, 4)), detail_seed=int(rng.integers(2**31))))
    return tuple(designs)


def straight_runs(xy: np.ndarray, min_length: float = MIN_DESIGN_M,
                  tolerance_deg: float = STRAIGHT_TOLERANCE_DEG) -> list[tuple[float, float]]:
    """Arc-length intervals at least `min_length` long over which the path's heading stays within a range of
    `tolerance_deg` (greedy, in path order)."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    s = np.arange(0.0, arc[-1], _HEADING_STEP_M)
    if len(s) < 3:
        return []
    p = np.column_stack([np.interp(s, arc, xy[:, 0]), np.interp(s, arc, xy[:, 1])])
    d = np.gradient(p, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    tol = np.radians(tolerance_deg)
    runs, i = [], 0
    while i < len(s) - 1:
        lo = hi = heading[i]
        j = i
        while j + 1 < len(s) and max(hi, heading[j + 1]) - min(lo, heading[j + 1]) < tol:
            j += 1
            lo, hi = min(lo, heading[j]), max(hi, heading[j])
        if s[j] - s[i] >= min_length:
            runs.append((float(s[i]), float(s[j])))
            i = j + 1
        else:
            i += 1
    return runs


def _on_straight(runs: list[tuple[float, float]], s: float, reach: float) -> tuple[float, float] | None:
    """[start, end] of straight path at or after `s` (within `reach` m) at least MIN_DESIGN_M long."""
    for a, b in runs:
        start = max(a, s)
        if b - start >= MIN_DESIGN_M and start - s <= reach:
            return start, b
    return None


def plan_stretches(xy: np.ndarray, catalogue_share: float, hard_share: float, hard_kinds: tuple[str, ...],
                   n_designs: int, rng: np.random.Generator, hard_from: float = 0.0) -> tuple[Stretch, ...]:
    """Special stretches along the path `xy` covering about the given shares of it; the designs are used in
    shuffled rounds so each repeats as soon as the path is long enough. Designs, walls, tunnels and highways
    move on to the next straight run within reach; a design finding none leaves regular blocks, the others
    are laid where they are. No hard stretch begins before arc length `hard_from`: odometry starts with zero
    velocity and needs structure along the road to pick up the motion (KISS-ICP stalled in a tunnel at the
    start of KITTI-06)."""
    special = catalogue_share + hard_share
    if special <= 0:
        return ()
    total = float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())
    runs = straight_runs(xy)
    regular = _MEAN_SPECIAL * (1.0 - special) / special
    out: list[Stretch] = []
    rounds: list[int] = []
    s = float(rng.uniform(0.2, 1.0)) * regular
    while s < total:
        if rng.random() < catalogue_share / special:
            kind = DESIGN
        else:
            kind = str(hard_kinds[int(rng.integers(len(hard_kinds)))])
        length = float(rng.uniform(*_LENGTHS[kind]))
        if kind != DESIGN:
            s = max(s, hard_from)
        straight = _on_straight(runs, s, _LENGTHS[DESIGN][1]) if kind in STRAIGHT_KINDS else None
        if straight is not None:
            s, length = straight[0], min(length, straight[1] - straight[0])
        elif kind == DESIGN:  # no straight street near: regular blocks where the design would have been
            s += length + float(rng.uniform(0.5, 1.5)) * regular
            continue
        design = -1
        if kind == DESIGN:
            if not rounds:
                rounds = list(rng.permutation(n_designs))
            design = int(rounds.pop())
        out.append(Stretch(s, min(s + length, total), kind, design))
        s += length + float(rng.uniform(0.5, 1.5)) * regular
    return tuple(out)
