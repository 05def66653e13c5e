"""Which verified loops the pose graph uses: pairwise consistency (PCM, Mangelson et al., ICRA 2018), decided
before optimisation.

Why before: a robust kernel on whitened loop residuals cannot tell a wrong loop from a true loop that has to
correct large drift; both have large residuals, so both are discounted (a Cauchy kernel of scale 1 leaves a
loop correcting 28 m with a 1 m sigma about 1/800 of its weight). Consistency asks a question drift does
not disturb: two loops (i, j) and (k, l) are consistent when the cycle loop a, odometry j -> l, loop b back,
odometry k -> i closes within what the two loops' covariances and the odometry covariance accumulated along
the two short paths i -> k and j -> l allow (chi-square test, 6 degrees of freedom). Two true loops at one
revisit agree however far the robot drifted in between; a wrong loop disagrees with them by its error.

The kept set is the largest set of pairwise consistent loops (a maximum clique of the consistency graph):
exact (Bron-Kerbosch with Tomita's pivot) while the search stays within MAX_CLIQUE_CALLS calls,
else greedy (the loop with most consistent partners first, then the one consistent with all chosen so far
that has most partners). Among maximum sets of equal size the one whose loops odometry finds most plausible
(smallest sum of single-loop chi-square values) is kept, so a single loop inconsistent with every other is
kept only when it is the most plausible alone. A loop without any partner (only one loop in the run) is
kept on its own evidence: registration and the drift gate of loop closing.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from msa_slam.backend.noise import PathCovariance, chi2_quantile

MAX_CLIQUE_CALLS = 200_000  # exact search budget; far above what tens of loops need


@dataclass(frozen=True)
class LoopEdge:
    """A loop as the graph holds it: keyframe positions `target` < or > `source` in the keyframe sequence,
    the measured T_target_source and the 6x6 covariance (rotation, translation) its factor has."""

    target: int
    source: int
    measured: np.ndarray
    covariance: np.ndarray


def _log(T: np.ndarray) -> np.ndarray:
    return gtsam.Pose3.Logmap(gtsam.Pose3(T))


def _adjoint(T: np.ndarray) -> np.ndarray:
    return gtsam.Pose3(T).AdjointMap()


def _chi2(residual: np.ndarray, covariance: np.ndarray) -> float:
    return float(residual @ np.linalg.solve(covariance, residual))


def single_chi2(loop: LoopEdge, path: PathCovariance) -> float:
    """How far the loop moves the odometry between its keyframes, in units of the odometry covariance
    accumulated between them plus the loop's own: r = Log(T_odometry^-1 T_loop) (in the source frame)."""
    odometry, cov = path.between(loop.target, loop.source)
    return _chi2(_log(np.linalg.inv(odometry) @ loop.measured), cov + loop.covariance)


def pair_chi2(a: LoopEdge, b: LoopEdge, path: PathCovariance) -> float:
    """Chi-square of the cycle T_a^-1 * odometry(a.target -> b.target) * T_b * odometry(b.source -> a.source),
    identity when both loops are right; its covariance is the two loops' and the two odometry paths'."""
    o1, c1 = path.between(a.target, b.target)
    o2, c2 = path.between(b.source, a.source)
    # Right perturbations of each factor of the product, carried to the cycle's end frame (a.source)
    ad = _adjoint
    inv_a = np.linalg.inv(a.measured)
    tail_b = b.measured @ o2  # what follows o1
    cov = (
        ad(np.linalg.inv(o1 @ tail_b))
        @ ad(a.measured)
        @ a.covariance
        @ ad(a.measured).T
        @ ad(np.linalg.inv(o1 @ tail_b)).T
    )
    cov += ad(np.linalg.inv(tail_b)) @ c1 @ ad(np.linalg.inv(tail_b)).T
    cov += ad(np.linalg.inv(o2)) @ b.covariance @ ad(np.linalg.inv(o2)).T
    cov += c2
    return _chi2(_log(inv_a @ o1 @ b.measured @ o2), 0.5 * (cov + cov.T))


@dataclass(frozen=True)
class InlierSelection:
    """The outcome: indices of the kept loops (in the order given), the method that found the set ("exact",
    "greedy", or "single" when there were fewer than two loops), and the bound used."""

    kept: tuple[int, ...]
    method: str
    threshold: float
    consistent_pairs: int


class ConsistencyGraph:
    """Loops and their pairwise consistency, grown one loop at a time. A pair's chi-square never changes once
    both loops exist (the keyframes' odometry is fixed when they are added), so each new loop is tested
    against the ones before it only: the online graph can ask for the maximum consistent set after every
    loop for the cost of the new pairs, and the batch graph builds the same graph at the end."""

    def __init__(self, confidence: float) -> None:
        self.threshold = chi2_quantile(confidence, 6)
        self._loops: list[LoopEdge] = []
        self._single: list[float] = []
        self._neighbours: list[set[int]] = []

    def __len__(self) -> int:
        return len(self._loops)

    def add(self, loop: LoopEdge, path: PathCovariance) -> None:
        """Enter `loop`; `path` holds the odometry covariance up to (at least) its newer keyframe."""
        new = len(self._loops)
        partners = {i for i, other in enumerate(self._loops) if pair_chi2(other, loop, path) <= self.threshold}
        for i in partners:
            self._neighbours[i].add(new)
        self._loops.append(loop)
        self._single.append(single_chi2(loop, path))
        self._neighbours.append(partners)

    def select(self) -> InlierSelection:
        """The maximum pairwise-consistent set of the loops entered so far."""
        n = len(self._loops)
        if n < 2:
            return InlierSelection(tuple(range(n)), "single", self.threshold, 0)
        clique, method = _maximum_clique(self._neighbours, np.array(self._single))
        pairs = sum(len(s) for s in self._neighbours) // 2
        return InlierSelection(tuple(sorted(clique)), method, self.threshold, pairs)


def select_inliers(loops: list[LoopEdge], path: PathCovariance, confidence: float) -> InlierSelection:
    """The maximum pairwise-consistent set of `loops` (chi-square quantile `confidence`, 6 dof)."""
    graph = ConsistencyGraph(confidence)
    for loop in loops:
        graph.add(loop, path)
    return graph.select()


def _better(candidate: set[int], best: set[int], score: np.ndarray) -> bool:
    """Larger wins; at equal size the set odometry finds more plausible (lower chi-square sum), then the
    one with lower indices, so the choice is deterministic."""
    if len(candidate) != len(best):
        return len(candidate) > len(best)
    a, b = float(score[list(candidate)].sum()), float(score[list(best)].sum())
    return a < b or a == b and sorted(candidate) < sorted(best)


class _SearchBudgetSpent(Exception):
    """The exact search used MAX_CLIQUE_CALLS calls: the greedy set is kept instead."""


def _maximum_clique(neighbours: list[set[int]], score: np.ndarray) -> tuple[set[int], str]:
    """Bron-Kerbosch with Tomita's pivot on an explicit stack, not by recursion: a maximum clique is as deep as it
    is large, and a revisit driven through twice can give a thousand consistent loops, beyond Python's recursion
    limit. The frames are visited in the recursive order, so the clique found is the same."""
    best: set[int] = set()
    calls = 0

    def enter(clique: set[int], candidates: set[int], excluded: set[int]) -> list | None:
        """A call of the recursive search: a frame to branch from, or None when it ends here."""
        nonlocal best, calls
        calls += 1
        if calls > MAX_CLIQUE_CALLS:
            raise _SearchBudgetSpent
        if not candidates and not excluded:
            if _better(clique, best, score):
                best = set(clique)
            return None
        if len(clique) + len(candidates) < len(best):  # cannot beat the best found
            return None
        pivot = max(candidates | excluded, key=lambda u: len(neighbours[u] & candidates))
        return [clique, candidates, excluded, sorted(candidates - neighbours[pivot]), 0]

    try:
        root = enter(set(), set(range(len(neighbours))), set())
        stack = [] if root is None else [root]
        while stack:
            frame = stack[-1]
            clique, candidates, excluded, branches, done = frame
            if done == len(branches):
                stack.pop()
                continue
            v = branches[done]
            child = enter(clique | {v}, candidates & neighbours[v], excluded & neighbours[v])
            # the later branches of this frame see v as excluded (the recursive search's loop update)
            frame[1], frame[2], frame[4] = candidates - {v}, excluded | {v}, done + 1
            if child is not None:
                stack.append(child)
    except _SearchBudgetSpent:
        return _greedy_clique(neighbours, score), "greedy"
    return best, "exact"


def _greedy_clique(neighbours: list[set[int]], score: np.ndarray) -> set[int]:
    order = sorted(range(len(neighbours)), key=lambda u: (-len(neighbours[u]), score[u], u))
    clique: set[int] = set()
    for u in order:
        if all(u in neighbours[v] for v in clique):
            clique.add(u)
    return clique
