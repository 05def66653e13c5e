"""Minimal Subset Approach (MSA): sliding-window keyframe sampling in descriptor space.

Section IV of the paper: frames accumulate in a window of N; once it is full, the subset that minimises
(alpha + rho) / (beta + pi) under the inter-pose distance bounds [lambda_l g, lambda_u g] becomes
keyframes, and the window slides so the last chosen frame starts the next one (unchosen frames are
re-evaluated with the new ones). With `neighbours > 0` nearby old keyframes join the window, as the
authors' example does at revisits.

The bookkeeping (the `index`/`widx` counters, when bounds update, which window members are candidates)
follows the authors' reference implementation exactly (../docs/msa-reference-semantics.md), so that the
keyframes are the same as theirs.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from msa_slam.errors import InputError
from msa_slam.sampling.base import AmbiguousWindow, Sampler, Timer
from msa_slam.sampling.msa_window import MODES, ExactWorkspace, ScoreWeights, optimise_window

MIN_WINDOW_STEP = 0.01  # a frame joins the window only if it moved this far from the last member
INITIAL_DMIN, INITIAL_DMAX = 1.0, 5.0
DMIN_FLOOR, DMAX_CAP = 0.01, 5.0


class MSASampler(Sampler):
    """MSA keyframe sampler (paper section IV; reference semantics).

    Parameters: window size N, alpha and beta (eq. 8), lambda_l / lambda_u (distance bounds as multiples
    of the running average step), neighbours (old keyframes near the window's end that join it; the
    authors' example uses 2), use_rho / use_pi (the paper's ablations), mode "exact" (bit-identical to the
    reference) or "fast" (Gram-matrix formulation, same result on >= 99 % of streams).
    """

    name = "msa"

    def __init__(self, window: int = 10, alpha: float = 1.0, beta: float = 1.0, lambda_l: float = 0.1,
                 lambda_u: float = 3.0, neighbours: int = 0, use_rho: bool = True, use_pi: bool = True,
                 mode: str = "exact") -> None:
        super().__init__()
        if int(window) != window or window < 3:
            raise ValueError(f"msa: window must be an integer >= 3, got {window}")
        if alpha <= 0 or beta <= 0:
            raise ValueError(f"msa: alpha and beta must be > 0, got alpha={alpha}, beta={beta}")
        if lambda_l < 0 or lambda_u <= 0 or lambda_l > lambda_u:
            raise ValueError(f"msa: need 0 <= lambda_l <= lambda_u and lambda_u > 0, "
                             f"got lambda_l={lambda_l}, lambda_u={lambda_u}")
        if int(neighbours) != neighbours or neighbours < 0:
            raise ValueError(f"msa: neighbours must be an integer >= 0, got {neighbours}")
        if mode not in MODES:
            raise ValueError(f"msa: mode must be one of {', '.join(MODES)}, got {mode!r}")
        self.window_size = int(window)
        self.lambda_l, self.lambda_u = float(lambda_l), float(lambda_u)
        self.neighbours = int(neighbours)
        self.mode = mode
        self.weights = ScoreWeights(float(alpha), float(beta), bool(use_rho), bool(use_pi))
        self._window: list[int] = []
        self._keyframe_set: set[int] = set()
        self._translation: dict[int, np.ndarray] = {}
        self._descriptor: dict[int, np.ndarray] = {}
        self._index = 0  # the reference's counters: not always len(keyframes) and len(window)
        self._widx = 0
        self._avg_step = 0.0
        self.dmin, self.dmax = INITIAL_DMIN, INITIAL_DMAX
        self._tree: cKDTree | None = None
        self._tree_size = 0
        self._workspace = ExactWorkspace()

    @property
    def window(self) -> list[int]:
        """Current window members (frame indices)."""
        return list(self._window)

    def _push(self, index, pose, descriptor, points):
        if descriptor is None:
            raise InputError(f"msa: frame {index} needs a descriptor")
        self._translation[index] = pose[:3, 3].copy()
        self._descriptor[index] = descriptor
        new: list[int] = []
        if self._index == 0:
            new += self._add_keyframe(index)
            self._index += 1
            self._window.append(index)
            self._widx += 1
        if self._widx < self.window_size:
            last = self._window[-1]
            if np.linalg.norm(self._translation[index] - self._translation[last]) >= MIN_WINDOW_STEP:
                self._window.append(index)
                self._widx += 1
            if self.neighbours > 0 and self._index >= self.window_size:
                self._add_neighbour_keyframes()
        if self._widx >= self.window_size:
            new += self._optimise(self._widx)
        self._forget([index])
        return new

    def _finish(self) -> list[int]:
        """Flush: optimise whatever is left in the window over all its members (not in the reference)."""
        if len(self._window) < 2:
            return []
        self._update_bounds()
        return self._optimise(len(self._window), update_bounds=False)

    def _add_keyframe(self, frame: int) -> list[int]:
        if frame in self._keyframe_set:
            return []
        self._keyframe_set.add(frame)
        return [frame]

    def _add_neighbour_keyframes(self) -> None:
        """Old keyframes near the window's newest member join the window (revisits)."""
        keyframes = self._online
        if self._tree is None or self._tree_size != len(keyframes):
            self._tree = cKDTree(np.array([self._translation[k] for k in keyframes]))
            self._tree_size = len(keyframes)
        anchor = self._translation[self._window[-1]]
        k = min(self.neighbours, self._tree_size)
        _, found = self._tree.query(anchor, k=k)
        for pos in np.atleast_1d(found)[1:]:
            frame = keyframes[int(pos)]
            if np.linalg.norm(self._translation[frame] - anchor) <= self.dmax and frame not in self._window:
                self._window.append(frame)
                self._widx += 1

    def _update_bounds(self) -> None:
        """Adapt [dmin, dmax] to the running average step length (paper: lambda_l, lambda_u)."""
        pts = np.array([self._translation[f] for f in self._window])
        avg = float(np.mean(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
        self._avg_step = avg if self._avg_step == 0 else (self._avg_step + avg) / 2
        g = self._avg_step
        self.dmin = self.lambda_l * g if g > DMIN_FLOOR else DMIN_FLOOR
        self.dmax = self.lambda_u * g if g < DMAX_CAP else DMAX_CAP

    def _optimise(self, n: int, update_bounds: bool = True) -> list[int]:
        """Solve the window over its first n members, emit the chosen keyframes, slide the window."""
        with Timer() as timer:
            if update_bounds:
                self._update_bounds()
            members = self._window[:n]
            result = optimise_window(
                np.array([self._translation[f] for f in members]),
                np.array([self._descriptor[f] for f in members]),
                self.dmin, self.dmax, self.weights, self.mode, self._workspace)
        self.stats.window_optimisations += 1
        self.stats.candidates_evaluated += result.candidates
        self.stats.optimisation_ms.append(timer.ms)
        if result.ambiguous:
            self.stats.ambiguous.append(AmbiguousWindow(self.stats.frames - 1, tuple(members),
                                                        len(self._online), result.margin))
        new: list[int] = []
        for pos in result.positions[1:]:
            new += self._add_keyframe(self._window[pos])
        dropped = self._window[:result.positions[-1]]
        self._window = self._window[result.positions[-1]:]
        self._widx = len(self._window) - 1
        self._index = len(self._keyframe_set) - 1
        self._forget(dropped)
        return new

    def _forget(self, frames: list[int]) -> None:
        """Drop poses/descriptors no longer needed: memory stays O(N), plus keyframes if neighbours > 0."""
        for frame in frames:
            if frame in self._translation and frame not in self._window and not (
                    self.neighbours > 0 and frame in self._keyframe_set):
                del self._translation[frame]
                del self._descriptor[frame]
