"""The MSA sampler: paper section IV-C as a sliding window over the stream.

Frames accumulate in a window of N; once it is full, the subset of its members that minimises
(alpha + rho) / (beta + pi) under the inter-pose distance bounds becomes keyframes, and the window
slides so that the last chosen frame starts the next one (unchosen later frames are evaluated again
with the new ones). With `neighbours > 0`, nearby old keyframes join the window, as the authors'
example does at revisits. The bookkeeping follows the authors' reference implementation exactly
(docs/msa.md), so that the keyframes are theirs.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from msa_slam.sampling.base import AmbiguousWindow, Sampler, Timer
from msa_slam.sampling.msa.exact import ExactWorkspace
from msa_slam.sampling.msa.params import MSAParams
from msa_slam.sampling.msa.terms import ScoreWeights
from msa_slam.sampling.msa.window import fell_back, optimise_window

MIN_WINDOW_STEP = 0.01  # a frame joins the window only if it moved this far from the last member
INITIAL_DMIN, INITIAL_DMAX = 1.0, 5.0  # the bounds before the first window is optimised
DMIN_FLOOR, DMAX_CAP = 0.01, 5.0  # the reference's limits on the bounds, in metres
FALLBACK_WARN_MIN = 3  # a warning from this many fallback windows, when they are also most windows so far


def warn_short_stream(
    frames: int, window: int, members: int | None = None, flush: bool = False, held: int = 0, min_motion: float = 0.0
) -> None:
    """The window never filled: no subset was ever optimised, so only frame 0 is an online keyframe. Either the
    stream is shorter than the window or (`members`, the frames that joined it) the frames did not move (`held`
    of them held back by the standstill gate, which `min_motion` sets). With `flush` (the caller flushes at the
    end) the end-of-stream flush picks the rest, so flushing is not advised."""
    if members is None or frames < window:
        why = f"window={window} is longer than the stream ({frames} frames): the window never filled"
    else:
        gate = f"; the standstill gate held back {held} that moved < {min_motion:g} m" if held else ""
        why = (
            f"window={window}: the window never filled in {frames} frames (only {members} moved at least "
            f"{MIN_WINDOW_STEP} m from the member before them{gate})"
        )
    advice = (
        "only the end-of-stream flush chooses keyframes after it; use a smaller window"
        if flush
        else "use a smaller window or flush at the end"
    )
    warnings.warn(f"msa: {why}, so only frame 0 was selected online; {advice}", UserWarning, stacklevel=3)


class MSASampler(Sampler):
    """MSA keyframe sampler (paper section IV; reference semantics).

    Parameters (MSAParams, msa/params.py): window size N, alpha and beta (eq. 8), lambda_l / lambda_u (distance
    bounds as multiples of the running average step, eq. 7), neighbours (old keyframes near the window's end that
    join it; the authors' example uses 2), use_rho / use_pi (the paper's ablations), mode "exact" (the reference's
    floating-point path) or "fast" (Gram-matrix formulation), pi "reference" (LAPACK's eigenvectors, the
    authors' keyframes) or "canonical" (eigenvectors fixed from the data alone: the same keyframes on
    every machine, msa/canonical.py). Windows whose choice rounding could change are counted in
    `stats.ambiguous` (msa/decision.py); windows whose bounds admitted no candidate in
    `stats.fallback_windows`, with a warning once they are most of them. min_motion / min_rotation: the
    standstill gate of every sampler (sampling/base.py; off by default, as in the reference, whose keyframes
    the parity tests check; the SLAM pipelines switch it on): odometry jitter at a standstill moves frames by
    more than MIN_WINDOW_STEP (1 cm), so without the gate a robot that stands still keeps filling windows and
    making keyframes.
    """

    name = "msa"
    Params = MSAParams
    params: MSAParams
    needs_descriptors = True

    def __init__(self, params: MSAParams | None = None, /, **given: Any) -> None:
        super().__init__(params, **given)
        p = self.params
        self.window_size, self.neighbours, self.mode, self.pi = p.window, p.neighbours, p.mode, p.pi
        self.lambda_l, self.lambda_u = p.lambda_l, p.lambda_u
        self.weights = ScoreWeights(p.alpha, p.beta, p.use_rho, p.use_pi)
        self._window: list[int] = []
        self._keyframe_set: set[int] = set()
        self._translation: dict[int, np.ndarray] = {}
        self._descriptor: dict[int, np.ndarray] = {}
        # The reference's two counters, kept as it keeps them (they are not len(keyframes), len(window)):
        # `_index` is 1 after the first frame and len(keyframes) - 1 after every optimisation; it marks the
        #   first frame (0) and lets old keyframes join the window once it reaches N.
        # `_widx` counts the window members the next optimisation uses; after a slide it is len(window) - 1,
        #   so from the second window on the newest member waits for the window after.
        self._index = 0
        self._widx = 0
        self._fallback_warned = False  # _warn_fallback_windows warns once a stream
        self._avg_step = 0.0  # g of eq. (7): running average step, halved towards each window's mean
        self.dmin, self.dmax = INITIAL_DMIN, INITIAL_DMAX
        self._tree: cKDTree | None = None
        self._tree_size = 0
        self._workspace = ExactWorkspace()

    def expect_frames(self, frames: int, flush: bool = False) -> None:
        """Warn up front when the stream is too short for the window ever to fill."""
        if frames < self.window_size:
            warn_short_stream(frames, self.window_size, flush=flush)

    @property
    def nbytes(self) -> int:
        """The base's records plus the buffered translations and descriptors, the window and the keyframe set
        (8 bytes an index): bounded by the window unless neighbours > 0 (keyframes' poses and descriptors)."""
        buffered = sum(t.nbytes for t in self._translation.values()) + sum(d.nbytes for d in self._descriptor.values())
        return super().nbytes + buffered + 8 * (len(self._window) + len(self._keyframe_set))

    @property
    def window(self) -> list[int]:
        """Current window members (frame indices)."""
        return list(self._window)

    def _push(self, index, pose, descriptor, points):
        self._translation[index] = pose[:3, 3].copy()
        self._descriptor[index] = descriptor
        new: list[int] = []
        if self._index == 0:  # the first frame is a keyframe and opens the window
            new += self._add_keyframe(index)
            self._index += 1
            self._join(index)
        if self._widx < self.window_size:  # fill: a frame that moved joins; at revisits, old keyframes too
            if np.linalg.norm(self._translation[index] - self._translation[self._window[-1]]) >= MIN_WINDOW_STEP:
                self._join(index)
            if self.neighbours > 0 and self._index >= self.window_size:
                self._add_neighbour_keyframes()
        if self._widx >= self.window_size:
            new += self._optimise(self._widx)
        self._forget([index])
        return new

    def _finish(self) -> list[int]:
        """Flush: optimise whatever is left in the window over all its members (not in the reference)."""
        if self.stats.window_optimisations == 0 and self.stats.frames > 0:
            warn_short_stream(
                self.stats.frames,
                self.window_size,
                len(self._window),
                flush=True,
                held=self.stats.standstill_frames,
                min_motion=self.min_motion,
            )
        if len(self._window) < 2:
            return []
        self._update_bounds()
        return self._optimise(len(self._window), update_bounds=False)

    def _warn_fallback_windows(self) -> None:
        """Once, as soon as most windows so far (at least FALLBACK_WARN_MIN) admitted no candidate under the
        distance bounds: their keyframes (each window's first and last member) were then fixed by the window
        length, not chosen by the score, and nothing else says so (whether or not the stream is finished)."""
        fallbacks, windows = self.stats.fallback_windows, self.stats.window_optimisations
        if self._fallback_warned or fallbacks < FALLBACK_WARN_MIN or 2 * fallbacks <= windows:
            return
        self._fallback_warned = True
        warnings.warn(
            f"msa: {fallbacks} of the {windows} windows so far had no subset whose consecutive members lie "
            f"within the distance bounds (last [{self.dmin:.3g}, {self.dmax:.3g}] m for an average step of "
            f"{self._avg_step:.3g} m), so each kept only its first and last member; check "
            f"lambda_l={self.lambda_l:g} and lambda_u={self.lambda_u:g}",
            UserWarning,
            stacklevel=5,
        )

    def _optimise(self, n: int, update_bounds: bool = True) -> list[int]:
        """Section IV-C over the window's first n members; returns the frames that became keyframes."""
        with Timer() as timer:
            if update_bounds:  # 1. bounds, eq. (7), from the running average step
                self._update_bounds()
            members = self._window[:n]  # 2-3. terms and score of every candidate subset, eqs. (3)-(8)
            translations = np.array([self._translation[f] for f in members])
            result = optimise_window(
                translations,
                np.array([self._descriptor[f] for f in members]),
                self.dmin,
                self.dmax,
                self.weights,
                self.mode,
                self._workspace,
                self.pi,
            )
        self._record(result, members, timer.ms)
        self.stats.fallback_windows += fell_back(result, translations, self.dmin, self.dmax)
        self._warn_fallback_windows()
        new: list[int] = []  # 4. emit: the chosen members after the first (already a keyframe)
        for pos in result.positions[1:]:
            new += self._add_keyframe(self._window[pos])
        last = result.positions[-1]  # 5. slide: the last chosen member opens the next window
        dropped, self._window = self._window[:last], self._window[last:]
        self._widx = len(self._window) - 1
        self._index = len(self._keyframe_set) - 1
        self._forget(dropped)
        return new

    def _update_bounds(self) -> None:
        """Eq. (7): dmin = lambda_l g, dmax = lambda_u g, g the running average step (the reference
        halves g towards each window's mean step and keeps dmin >= 0.01 m, dmax <= 5 m)."""
        pts = np.array([self._translation[f] for f in self._window])
        avg = float(np.mean(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
        self._avg_step = avg if self._avg_step == 0 else (self._avg_step + avg) / 2
        g = self._avg_step
        self.dmin = self.lambda_l * g if g > DMIN_FLOOR else DMIN_FLOOR
        self.dmax = self.lambda_u * g if g < DMAX_CAP else DMAX_CAP

    def _record(self, result, members: list[int], ms: float) -> None:
        self.stats.window_optimisations += 1
        self.stats.candidates_evaluated += result.candidates
        self.stats.optimisation_ms.append(ms)
        if result.ambiguous:
            self.stats.ambiguous.append(
                AmbiguousWindow(self.stats.frames - 1, tuple(members), len(self._online), result.margin)
            )

    def _join(self, frame: int) -> None:
        self._window.append(frame)
        self._widx += 1

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
        _, found = self._tree.query(anchor, k=min(self.neighbours, self._tree_size))
        for pos in np.atleast_1d(found)[1:]:  # the nearest is dropped, as the reference does
            frame = keyframes[int(pos)]
            if np.linalg.norm(self._translation[frame] - anchor) <= self.dmax and frame not in self._window:
                self._join(frame)

    def _forget(self, frames: list[int]) -> None:
        """Drop poses/descriptors no longer needed: memory stays O(N), plus keyframes if neighbours > 0."""
        for frame in frames:
            if (
                frame in self._translation
                and frame not in self._window
                and not (self.neighbours > 0 and frame in self._keyframe_set)
            ):
                del self._translation[frame]
                del self._descriptor[frame]
