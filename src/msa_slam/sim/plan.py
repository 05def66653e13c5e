"""What goes where along the path: stretches laid out from a small catalogue of street designs (as real
suburbs repeat house types, so distant places look alike) and hard stretches where ICP degenerates along
the travel direction (open fields, long plain walls, tunnels, highways between barriers).

The rest of the path is laid out block by block as before; with no shares the plan is empty.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

if TYPE_CHECKING:
    from msa_slam.sim.layout import Style

HARD_KINDS: tuple[str, ...] = ("field", "wall", "tunnel", "highway")
DESIGN = "design"
_LENGTHS = {"field": (80.0, 200.0), "wall": (100.0, 250.0), "tunnel": (60.0, 150.0), "highway": (150.0, 300.0)}
_MEAN_HARD = 170.0
_MIN_HARD_M = 40.0  # a hard stretch squeezed shorter than this between designs is left out
STRAIGHT_TOLERANCE_DEG = 25.0  # heading range within a straight run
MIN_DESIGN_M = 100.0  # shortest designed stretch (a straight run's remainder shorter than this stays regular)
MAX_DESIGN_M = 260.0  # longer straight runs get several designs (one design all along would hide true revisits)
_DESIGN_BREAK = (20.0, 50.0)  # m of regular street between two designed stretches of one straight run
_HEADING_STEP_M = 2.0
REVISIT_RADIUS_M = 10.0  # a path point this close to the path driven earlier re-drives that road
_REVISIT_BEHIND_M = 60.0  # ... unless that part is less than this far back along the path (a bend)
_MIN_REVISIT_M = 30.0  # a shorter re-driven interval is a crossing, not a revisit: it stays in the plan


@dataclass(frozen=True)
class Stretch:
    """Arc-length interval [start, end) of the path with a kind ("design" or a hard kind)."""

    start: float
    end: float
    kind: str
    design: int = -1
    order_offset: int = 0  # where this instance of the design starts in the design's order of house variants


ORDER_LENGTH = 97  # house variants in a design's fixed order (prime, longer than any row: never periodic)


@dataclass(frozen=True)
class HouseVariant:
    """One house type of a design: its length along the street, its height, and whether a back-row block and a
    front-garden tree go with it."""

    length: float
    height: float
    back: tuple[float, float, float] | None  # length, depth, height of a block behind the house
    tree: bool


@dataclass(frozen=True)
class Design:
    """A street design: houses of a few types (`variants`) at a fixed pitch on both sides, in an irregular order
    fixed by the design (`order_seed`), each with the same garden wall closing the gap to the next house (so what
    lies behind, different at every place, stays hidden), optional back-row block, front-garden tree, low front
    fence and street light; `detail_seed` fixes the facade detail. Every instance of the design runs through the
    same order from its own starting point (Stretch.order_offset): as in a real suburb, two streets of it share
    house types and now and then a run of them in the same order, and no street repeats itself at a fixed pitch
    (identical houses at one pitch made a place look like the place a few houses back)."""

    length: float
    depth: float
    height: float
    setback: float
    pitch: float
    refl: float
    back: tuple[float, float, float] | None  # length, depth, height of a block behind each house
    tree_pitch: int  # a tree every this many houses (0: none)
    fence: float  # fence height (0: none)
    light_pitch: int  # a street light every this many houses (0: none)
    detail_seed: int
    gap_wall: float = 0.0  # height of the wall between two houses (0: an open gap)
    variants: tuple[HouseVariant, ...] = ()  # house types (empty: every house is the design's own)
    order_seed: int = 0

    def variant_order(self) -> np.ndarray:
        """The design's fixed irregular order of house types: ORDER_LENGTH indices into `variants`."""
        if len(self.variants) < 2:
            return np.zeros(ORDER_LENGTH, dtype=int)
        return np.random.default_rng([self.order_seed, 7]).integers(len(self.variants), size=ORDER_LENGTH)

    def house(self, order: np.ndarray, k: int) -> HouseVariant:
        """The type of the k-th house counted from the order's start."""
        if not self.variants:
            return HouseVariant(self.length, self.height, self.back, bool(self.tree_pitch))
        return self.variants[int(order[k % ORDER_LENGTH])]


def make_catalogue(n: int, style: Style, rng: np.random.Generator, variants: int = 1) -> tuple[Design, ...]:
    """`n` designs within the style's ranges (mid-height blocks, as residential streets). They share one
    building line (setback), as a town's planning rules fix it. With `variants` > 1 each design has that many
    house types, differing in height, back-row block and tree; with 1 every house of a design is the same."""
    designs = []
    setback = float(rng.uniform(*style.setback))
    for _ in range(n):
        lo, hi = style.length
        length = float(rng.uniform(lo + 2.0, (lo + hi) / 2 + 2.0))
        h_lo, h_hi = style.height
        back = None
        if rng.random() < 0.5:
            back = (
                float(rng.uniform(*style.length)),
                float(rng.uniform(*style.depth)),
                float(rng.uniform(h_lo + 4.0, h_hi)),
            )
        designs.append(
            Design(
                length=length,
                depth=float(rng.uniform(*style.depth)),
                height=float(rng.uniform(h_lo + 2.0, h_lo + 0.6 * (h_hi - h_lo))),
                setback=setback,
                pitch=length + float(rng.uniform(*style.gap)),
                refl=float(rng.uniform(0.35, 0.75)),
                back=back,
                tree_pitch=int(rng.integers(0, 2)),
                fence=float(rng.uniform(0.8, 1.6)) if rng.random() < 0.5 else 0.0,
                light_pitch=int(rng.integers(0, 2)),
                detail_seed=int(rng.integers(2**31)),
                gap_wall=float(rng.uniform(2.6, 3.4)),
            )
        )
    if variants < 2:
        return tuple(designs)
    return tuple(
        replace(d, variants=_house_variants(d, variants, style, rng), order_seed=int(rng.integers(2**31)))
        for d in designs
    )


def _house_variants(design: Design, n: int, style: Style, rng: np.random.Generator) -> tuple[HouseVariant, ...]:
    """The design's own house and n - 1 types differing from it in length (so the gaps between houses fall
    irregularly), by 3-6 m of height and, each at even odds, in having a back-row block and a tree (what Scan
    Context's height bins see)."""
    h_lo, h_hi = style.height
    lo, hi = style.length
    back = design.back or (
        float(rng.uniform(*style.length)),
        float(rng.uniform(*style.depth)),
        float(rng.uniform(h_lo + 4.0, h_hi)),
    )
    out = [HouseVariant(design.length, design.height, design.back, bool(design.tree_pitch))]
    for _ in range(n - 1):
        step = float(rng.uniform(3.0, 6.0)) * (1.0 if rng.random() < 0.5 else -1.0)
        height = design.height + step
        if not h_lo <= height <= h_hi:
            height = design.height - step
        out.append(
            HouseVariant(
                float(rng.uniform(lo + 2.0, (lo + hi) / 2 + 2.0)),
                float(np.clip(height, h_lo, h_hi)),
                back if rng.random() < 0.5 else None,
                bool(rng.random() < 0.5),
            )
        )
    return tuple(out)


def straight_runs(
    xy: np.ndarray, min_length: float = MIN_DESIGN_M, tolerance_deg: float = STRAIGHT_TOLERANCE_DEG
) -> list[tuple[float, float]]:
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


def first_visits(xy: np.ndarray) -> list[tuple[float, float]]:
    """Arc-length intervals of the path that do not re-drive a road driven before (what a revisit sees was
    laid out on the first visit: planning it again would lay a second design or a hard stretch over the
    first visit's, and on a lap driven twice (KITTI-06) leave neither as planned)."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    s = np.arange(0.0, arc[-1], _HEADING_STEP_M)
    if len(s) < 2:
        return [(0.0, float(arc[-1]))]
    p = np.column_stack([np.interp(s, arc, xy[:, 0]), np.interp(s, arc, xy[:, 1])])
    near = cKDTree(p).query_ball_point(p, REVISIT_RADIUS_M)
    behind = int(_REVISIT_BEHIND_M / _HEADING_STEP_M)
    revisit = np.array([min(js) < i - behind for i, js in enumerate(near)])
    edges = np.flatnonzero(np.diff(np.concatenate([[False], revisit, [False]]).astype(np.int8)))
    out, a = [], 0.0
    for lo, hi in zip(edges[::2], edges[1::2]):
        if s[hi - 1] - s[lo] >= _MIN_REVISIT_M:
            out.append((a, float(s[lo])))
            a = float(s[hi - 1])
    out.append((a, float(arc[-1])))
    return [(lo, hi) for lo, hi in out if hi - lo >= REVISIT_RADIUS_M]  # not the end of a revisit's last sample


def _runs_within(runs: list[tuple[float, float]], keep: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The parts of `runs` inside the `keep` intervals that are still at least MIN_DESIGN_M long."""
    out = [(max(a, lo), min(b, hi)) for a, b in runs for lo, hi in keep]
    return [(a, b) for a, b in out if b - a >= MIN_DESIGN_M]


def _design_pieces(
    runs: list[tuple[float, float]], total: float, share: float, rng: np.random.Generator
) -> list[tuple[float, float]]:
    """Whole straight runs, in a seeded order, until about `share` of the path is covered; a run longer than
    MAX_DESIGN_M is cut into pieces with regular blocks between them."""
    pieces: list[tuple[float, float]] = []
    covered = 0.0
    for k in rng.permutation(len(runs)):
        a, b = runs[int(k)]
        if pieces and covered + min(b - a, MAX_DESIGN_M) > share * total:
            continue
        while b - a >= MIN_DESIGN_M:
            length = b - a if b - a <= MAX_DESIGN_M else float(rng.uniform(MIN_DESIGN_M + 50.0, MAX_DESIGN_M))
            pieces.append((a, a + length))
            covered += length
            a += length + float(rng.uniform(*_DESIGN_BREAK))
    return sorted(pieces)


def plan_stretches(
    xy: np.ndarray,
    catalogue_share: float,
    hard_share: float,
    hard_kinds: tuple[str, ...],
    n_designs: int,
    rng: np.random.Generator,
    hard_from: float = 0.0,
) -> tuple[Stretch, ...]:
    """Special stretches along the path `xy` covering about the given shares of it.

    Designs come first and take whole straight runs (Scan Context sees 80 m along a street: two places of a
    design look alike only where the design lines the street that far both ways), used in shuffled rounds so
    each repeats as soon as the path is long enough. Hard stretches fill about `hard_share` of the path in
    between, none beginning before arc length `hard_from`: odometry starts with zero velocity and needs
    structure along the road to pick up the motion (KISS-ICP stalled in a tunnel at the start of KITTI-06).
    Only first visits are planned (`first_visits`): a revisit sees what its first visit laid out."""
    if catalogue_share + hard_share <= 0:
        return ()
    visits = first_visits(xy)
    total = sum(b - a for a, b in visits)
    if total <= 0:
        return ()
    out: list[Stretch] = []
    if catalogue_share > 0:
        rounds: list[int] = []
        for a, b in _design_pieces(_runs_within(straight_runs(xy), visits), total, catalogue_share, rng):
            if not rounds:
                rounds = list(rng.permutation(n_designs))
            out.append(Stretch(a, b, DESIGN, int(rounds.pop()), int(rng.integers(ORDER_LENGTH))))
    if hard_share > 0:
        revisits = [Stretch(b, a, "revisit") for (_, b), (a, _) in zip(visits, visits[1:])]
        out += _hard_stretches(visits[-1][1], total, hard_share, hard_kinds, out + revisits, rng, hard_from)
    return tuple(sorted(out, key=lambda x: x.start))


def _hard_stretches(
    end_arc: float,
    total: float,
    share: float,
    kinds: tuple[str, ...],
    taken: list[Stretch],
    rng: np.random.Generator,
    hard_from: float,
) -> list[Stretch]:
    """About `share` of the path's `total` first-visit length in hard stretches laid between the `taken`
    intervals (designs and re-driven roads; shortened to fit)."""
    taken = sorted(taken, key=lambda x: x.start)
    free = total - sum(d.end - d.start for d in taken if d.kind == DESIGN)
    regular = _MEAN_HARD * max(free / total - share, 0.05) / share
    out: list[Stretch] = []
    s = max(float(rng.uniform(0.2, 1.0)) * regular, hard_from)
    while s < end_arc:
        kind = str(kinds[int(rng.integers(len(kinds)))])
        end = min(s + float(rng.uniform(*_LENGTHS[kind])), end_arc)
        inside = next((d for d in taken if d.start - _DESIGN_BREAK[0] <= s < d.end), None)
        if inside is not None:  # starts in a design or on a re-driven road: after it
            s = inside.end + float(rng.uniform(*_DESIGN_BREAK))
            continue
        ahead = [d.start for d in taken if d.start > s]
        if ahead:
            end = min(end, ahead[0] - _DESIGN_BREAK[0])
        if end - s >= _MIN_HARD_M:
            out.append(Stretch(s, end, kind))
        s = end + float(rng.uniform(0.5, 1.5)) * regular
    return out
