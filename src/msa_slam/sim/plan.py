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


def plan_stretches(total: float, catalogue_share: float, hard_share: float, hard_kinds: tuple[str, ...],
                   n_designs: int, rng: np.random.Generator) -> tuple[Stretch, ...]:
    """Special stretches over [0, total) covering about the given shares of the path; the designs are
    used in shuffled rounds so each repeats as soon as the path is long enough."""
    special = catalogue_share + hard_share
    if special <= 0:
        return ()
    regular = _MEAN_SPECIAL * (1.0 - special) / special
    out: list[Stretch] = []
    rounds: list[int] = []
    s = float(rng.uniform(0.2, 1.0)) * regular
    while s < total:
        if rng.random() < catalogue_share / special:
            if not rounds:
                rounds = list(rng.permutation(n_designs))
            kind, design = DESIGN, int(rounds.pop())
        else:
            kind, design = str(hard_kinds[int(rng.integers(len(hard_kinds)))]), -1
        length = float(rng.uniform(*_LENGTHS[kind]))
        out.append(Stretch(s, min(s + length, total), kind, design))
        s += length + float(rng.uniform(0.5, 1.5)) * regular
    return tuple(out)
