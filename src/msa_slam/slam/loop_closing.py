"""Loop closing for each new keyframe (paper, section V-A): descriptor search, then verification.

A new keyframe queries the older keyframes by descriptor, leaving out the most recent ones and those
fewer than `min_travel_m` metres back along the odometry path (a revisit, not a standstill); its best
match is recorded for the PR curve, and matches at or above the similarity threshold are loop candidates.
`oracle` mode (the paper) verifies only candidates within `loop_radius` of each other in ground truth;
`realistic` mode verifies every candidate. Verification registers the two downsampled keyframe clouds;
the loop is rejected when the clouds are too sparse, overlap too little, have too few inliers or too
large a residual (registration.verify), or (drift check on: by default in realistic mode) when its
correction of the odometry between the two keyframes is not explained by the odometry covariance
accumulated frame by frame along the path between them (the drift model's, backend/noise.py PathCovariance,
scaled to systematic growth beyond the model's reference length and widened `drift_gate` times in sigma),
the loop's own covariance and a slack (`drift_slack_m`,
`drift_slack_deg`: the correction allowed in one direction with no path at all): a chi-square test at
`drift_confidence`, 6 degrees of freedom.

What finds the candidates (`loop_detector`) and how they are accepted (`loop_protocol`, by default
"auto": paper in oracle mode, verified in realistic mode): the paper takes matches at or above `similarity_threshold` (best `top_k`) and
registers from the descriptor's yaw; "verified" takes the best `verified_top_k` above the floor
`verified_min_similarity` (0.3: below it Scan Context matches are noise even for local maps, and three
registrations a keyframe stay affordable) and lets registration decide, from the yaw plus a coarse translation
search (registration/coarse.py), or from MapClosures' own alignment, so no odometry prior is used, and verifies
strictly (the structure gate of registration/verify.py). Its loops join keyframes at most MAX_LOOP_OFFSET_M apart
and turn at most MAX_LOOP_TURN_DEG from the descriptor's yaw; with the drift check on, a candidate whose odometry
puts its keyframes so far apart, or whose descriptor yaw is so far from the odometry's heading, that no such loop
passes the drift check is rejected for drift before it is registered (most false candidates: it decides what
registration and the drift check would have, at a fraction of the cost), and a keyframe's cloud is prepared for
registration once for all its candidates (registration/prepared.py). An accepted loop
whose measured pose is off ground truth by more than `loop_radius` (or evaluation.loops.FALSE_LOOP_ANGLE_DEG) is a
false loop; one over at least 2 x `loop_radius` of path (the robot left the place and came back) is a revisit.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Protocol

import gtsam
import numpy as np

from msa_slam.backend.graph_config import GraphConfig
from msa_slam.backend.noise import PathCovariance, chi2_quantile
from msa_slam.descriptors import Descriptor
from msa_slam.errors import InputError
from msa_slam.evaluation.loops import rejection_counts
from msa_slam.evaluation.metrics import JSONValue, LoopClosing
from msa_slam.place_recognition import PRCurve, precision_recall
from msa_slam.registration import Verifier
from msa_slam.registration.coarse import coarse_guess
from msa_slam.registration.prepared import PreparedCloud
from msa_slam.registration.verify import REJECTIONS
from msa_slam.slam.keyframes import KeyframeStore
from msa_slam.slam.map_closures_detector import MapClosuresDetector
from msa_slam.types import LoopClosure


class LoopSettings(Protocol):
    """The loop-closing fields of the run configuration (msa_slam.pipeline.config.RunConfig), read-only: a config
    narrows some of them (`mode` is a Literal there), which a protocol attribute, being writable, would refuse."""

    @property
    def similarity_threshold(self) -> float: ...
    @property
    def min_frame_gap(self) -> int: ...
    @property
    def exclude_recent(self) -> int: ...
    @property
    def top_k(self) -> int: ...
    @property
    def mode(self) -> str: ...
    @property
    def loop_radius(self) -> float: ...
    @property
    def min_travel_m(self) -> float: ...
    @property
    def drift_check(self) -> str: ...
    @property
    def drift_gate(self) -> float: ...
    @property
    def drift_confidence(self) -> float: ...
    @property
    def drift_slack_m(self) -> float: ...
    @property
    def drift_slack_deg(self) -> float: ...
    @property
    def loop_detector(self) -> str: ...
    @property
    def loop_protocol(self) -> str: ...
    @property
    def verified_top_k(self) -> int: ...
    @property
    def verified_min_similarity(self) -> float: ...
    @property
    def graph(self) -> GraphConfig: ...


# every reason a registered candidate can be rejected for; "inconsistent": accepted by loop closing, then left out
# of the batch graph by the pairwise consistency check (backend/inliers.py)
REJECTION_REASONS = ("sparse", *REJECTIONS, "drift", "inconsistent")
# keyframe clouds kept prepared for registration (LoopCloser._prepared): a query's and the matches of the last few
# queries (consecutive keyframes match neighbouring ones), a few MB each
PREPARED_KEPT = 8
# The verified protocol joins keyframes at most this far apart: its coarse search starts within 8.5 m of the
# descriptor's guess, and GICP carried true loops on sim:test to 15.4 m; twice that is a view of the street from
# afar rather than a revisit. It bounds what a registration can return, so a candidate whose odometry puts its
# keyframes so far apart that no loop within it passes the drift check is rejected unregistered (beyond_drift).
MAX_LOOP_OFFSET_M = 30.0
# Its loops turn at most this far from the descriptor's yaw (Scan Context: 6 deg sectors): the translation search
# does not turn, GICP refines the yaw by a few degrees (at most 2.7 deg on simulated reverse-revisit), and a
# registration that turned further did not confirm the descriptor's view of the place. It bounds the loop's rotation,
# so a candidate whose descriptor yaw is that far beyond what the odometry's heading allows is rejected
# unregistered too (beyond_drift): on a street driven back the other way, most false candidates.
MAX_LOOP_TURN_DEG = 30.0


def yaw_guess(descriptor: Descriptor, query_desc: np.ndarray, match_desc: np.ndarray) -> np.ndarray:
    """Initial T_match_query: the descriptor's yaw estimate (Scan Context's best column shift), else identity."""
    guess = np.eye(4)
    if hasattr(descriptor, "align"):
        _, yaw_deg = descriptor.align(query_desc, match_desc)
        c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
        guess[:2, :2] = [[c, -s], [s, c]]
    return guess


def rotation_angle(rotation: np.ndarray) -> float:
    """The angle (radians, 0 to pi) of a rotation matrix."""
    return float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))


def within_search(T_match_query: np.ndarray, guess: np.ndarray) -> bool:
    """Whether a loop of the verified protocol is within its largest offset and turn from the descriptor's
    `guess` (MAX_LOOP_OFFSET_M, MAX_LOOP_TURN_DEG)."""
    turn = rotation_angle(guess[:3, :3].T @ T_match_query[:3, :3])
    return bool(np.linalg.norm(T_match_query[:3, 3]) <= MAX_LOOP_OFFSET_M and turn <= np.radians(MAX_LOOP_TURN_DEG))


class LoopCloser:
    """Candidates of a new keyframe among the stored ones, and their verification; keeps every query's best
    match (similarity, ground-truth distance) for the PR curve."""

    def __init__(
        self,
        store: KeyframeStore,
        verifier: Verifier,
        settings: LoopSettings,
        map_closures: MapClosuresDetector | None = None,
    ) -> None:
        self.store, self.verifier, self.settings = store, verifier, settings
        self.map_closures = map_closures  # the candidates' source when loop_detector is map-closures
        self.best_similarity: list[float] = []
        self.best_distance: list[float] = []
        self._path = np.zeros(1)  # odometry path length from frame 0 to each frame seen so far
        self._odometry = np.zeros((0, 4, 4))
        self._drift = PathCovariance()  # odometry covariance accumulated frame by frame (the drift check)
        self._guesses: dict[tuple[int, int], np.ndarray] = {}  # MapClosures' T_match_query by (query, match)
        self._prepared_clouds: dict[int, PreparedCloud] = {}  # by keyframe, least recently used first

    def candidates(
        self, frame: int, descriptor: np.ndarray, gt: np.ndarray, odometry: np.ndarray, cloud: np.ndarray | None = None
    ) -> list[LoopClosure]:
        """Older keyframes matching `frame` (call before adding it to the store); `gt` and `odometry` hold
        every frame's ground-truth and odometry poses up to `frame` (true-loop distance, travelled path);
        `cloud` is the keyframe's local map, which the map-closures detector queries with."""
        s = self.settings
        self._odometry = odometry
        path = self._path_to(frame)
        reachable = int(np.searchsorted(path, path[frame] - s.min_travel_m, side="right")) - 1
        gap = max(s.min_frame_gap, frame - reachable - 1)
        threshold, top_k = acceptance(s)
        if self.map_closures is not None:  # its own inlier threshold is the floor
            threshold, matches = 0.0, self._map_closure_matches(self.map_closures, frame, cloud, gap, top_k)
            if reachable >= 0 and not matches:
                self._record_miss(frame, gt, gap)
        elif reachable < 0:  # nothing far enough back along the path yet
            return []
        else:
            matches = self.store.database.query(
                frame, descriptor, exclude_frames=gap, exclude_recent=s.exclude_recent, threshold=0.0, top_k=top_k
            )
        if reachable < 0:
            return []
        out = []
        for rank, match in enumerate(matches):
            dist = float(np.linalg.norm(gt[frame, :3, 3] - gt[match.keyframe_id, :3, 3]))
            if rank == 0:
                self.best_similarity.append(match.similarity)
                self.best_distance.append(dist)
            if match.similarity >= threshold:
                out.append(
                    LoopClosure(
                        frame,
                        match.keyframe_id,
                        match.similarity,
                        dist,
                        travelled_m=float(path[frame] - path[match.keyframe_id]),
                    )
                )
        return out

    def _map_closure_matches(
        self, detector: MapClosuresDetector, frame: int, cloud: np.ndarray | None, gap: int, top_k: int
    ) -> list:
        """MapClosures' best `top_k` eligible keyframes for `frame` (it also enters `frame` into its database).
        The ineligible keyframes are the newest ones, so asking for top_k more than there are of them leaves
        top_k eligible ones whenever MapClosures finds that many."""
        if cloud is None:
            raise InputError(f"loop detector map-closures: keyframe {frame} has no local map")
        database = self.store.database
        eligible = database.eligible(frame, gap, self.settings.exclude_recent) if len(database) else np.zeros(0, bool)
        allowed = set(database.ids[eligible].tolist())
        found = detector.query(frame, cloud, top_k + int((~eligible).sum()))
        matches = [m for m in found if m.keyframe_id in allowed][:top_k]
        for m in matches:
            self._guesses[(frame, m.keyframe_id)] = m.T_match_query
        return matches

    def _record_miss(self, frame: int, gt: np.ndarray, gap: int) -> None:
        """A query MapClosures found nothing for is a PR point of similarity 0 at the nearest eligible keyframe
        (a missed revisit then counts against recall, as a low Scan Context score does)."""
        database = self.store.database
        eligible = database.eligible(frame, gap, self.settings.exclude_recent) if len(database) else np.zeros(0, bool)
        if eligible.any():
            ids = database.ids[eligible]
            self.best_similarity.append(0.0)
            self.best_distance.append(float(np.min(np.linalg.norm(gt[ids, :3, 3] - gt[frame, :3, 3], axis=1))))

    def _path_to(self, frame: int) -> np.ndarray:
        """Cumulative odometry path length up to `frame`, extended incrementally (frames never change)."""
        done = len(self._path)
        if frame >= done:
            steps = np.linalg.norm(np.diff(self._odometry[done - 1 : frame + 1, :3, 3], axis=0), axis=1)
            self._path = np.concatenate([self._path, self._path[-1] + np.cumsum(steps)])
        return self._path

    def _drift_to(self, frame: int) -> PathCovariance:
        """The accumulated odometry covariance up to `frame`, extended incrementally like the path length."""
        graph = self.settings.graph
        for k in range(len(self._drift), frame + 1):
            pose = self._odometry[k]
            self._drift.append(
                pose, graph.odometry_covariance(np.linalg.inv(self._odometry[k - 1]) @ pose) if k else None
            )
        return self._drift

    def verify(self, candidates: list[LoopClosure]) -> list[LoopClosure]:
        """Register candidate pairs (all in `realistic` mode, only GT-near ones in `oracle` mode)."""
        return [self._verify(c) for c in candidates]

    def _verify(self, cand: LoopClosure) -> LoopClosure:
        guess = self._guesses.pop((cand.query, cand.match), None)
        if self.settings.mode == "oracle" and cand.gt_distance > self.settings.loop_radius:
            return cand
        strict = protocol(self.settings) == "verified"
        searched = strict and guess is None  # registered from the descriptor's yaw and the coarse search
        if guess is None:
            store = self.store
            guess = yaw_guess(store.descriptor, store.descriptor_of(cand.query), store.descriptor_of(cand.match))
        if (
            searched
            and drift_check_on(self.settings)
            and self.beyond_drift(cand, MAX_LOOP_OFFSET_M, guess, MAX_LOOP_TURN_DEG)
        ):
            return replace(cand, verified=True, rejected="drift")  # no registration the search can return passes
        try:
            target, source = self._prepared(cand.match), self._prepared(cand.query)
            start = coarse_guess(target, source, guess, self.verifier.config) if searched else guess
            result = self.verifier.verify(target, source, initial_guess=start, strict=strict, coarse=not searched)
        except InputError:  # clouds too sparse to register: the candidate is rejected, not the run
            return replace(cand, verified=True, residual=float("inf"), rejected="sparse")
        rejected = result.rejected
        if not rejected and searched and not within_search(result.T_target_source, guess):
            rejected = "overlap"  # a view of the place from afar or askew, not a revisit (within_search)
        if (
            not rejected
            and drift_check_on(self.settings)
            and self.exceeds_drift(cand, result.T_target_source, result.covariance)
        ):
            rejected = "drift"
        return replace(
            cand,
            verified=True,
            accepted=not rejected,
            residual=result.residual,
            T_match_query=result.T_target_source,
            covariance=result.covariance,
            rejected=rejected,
        )

    def _prepared(self, frame: int) -> PreparedCloud:
        """The keyframe's cloud prepared for registration, kept for the next candidates (the query's own, and
        matches that recur for consecutive queries): the PREPARED_KEPT most recently used."""
        prepared = self._prepared_clouds.pop(frame, None)
        if prepared is None:
            prepared = self.verifier.prepare(self.store.cloud(frame), f"keyframe {frame}")
        self._prepared_clouds[frame] = prepared
        while len(self._prepared_clouds) > PREPARED_KEPT:
            del self._prepared_clouds[next(iter(self._prepared_clouds))]
        return prepared

    def exceeds_drift(self, cand: LoopClosure, T_match_query: np.ndarray, covariance: np.ndarray | None = None) -> bool:
        """Whether the loop's correction of the odometry between its keyframes is beyond what the drift check
        allows (drift_chi2 above the chi-square quantile `drift_confidence`, 6 dof)."""
        return self.drift_chi2(cand, T_match_query, covariance) > chi2_quantile(self.settings.drift_confidence, 6)

    def drift_chi2(self, cand: LoopClosure, T_match_query: np.ndarray, covariance: np.ndarray | None = None) -> float:
        """Chi-square of the correction Log(T_odometry^-1 T_match_query) (query frame) against drift_gate^2 times
        the odometry covariance accumulated along the frames between the keyframes, plus the loop factor's
        covariance (`covariance`: the registration's, bounded as the graph bounds it) and the slack, whose
        sigma is scaled so that a correction in one direction of exactly the slack sits on the bound.

        Why a covariance, not a per-metre allowance on the travelled distance: it follows the path, so a
        heading or pitch error picked up early moves the later positions sideways or vertically by the lever
        arm the path actually has, and it is the same quantity the pose graph weights odometry with. The drift
        model is a random walk calibrated over `graph.drift_reference_m`; odometry drift is mostly systematic
        (KITTI's relative error is about the same fraction of 100 m and 800 m segments), so over a longer path
        the covariance is scaled by path / reference: the sigma then grows with the path, not its square root
        (x2.6 over 690 m). The pose graph keeps the random walk: there it only weights the chain."""
        odometry, total = self._drift_covariance(cand, self.settings.graph.loop_covariance(covariance))
        correction = gtsam.Pose3.Logmap(gtsam.Pose3(np.linalg.inv(odometry) @ T_match_query))
        return float(correction @ np.linalg.solve(total, correction))

    def beyond_drift(
        self, cand: LoopClosure, reach_m: float, guess: np.ndarray | None = None, turn_deg: float = MAX_LOOP_TURN_DEG
    ) -> bool:
        """Whether every loop that puts the query within `reach_m` of the match (and, given the descriptor's
        `guess`, turns at most `turn_deg` from its rotation) fails the drift check, so the candidate need not be
        registered. A lower bound of drift_chi2 for any such loop: with E = T_odometry^-1 T_loop and
        Log(E) = (w, r), the chi-square is at least that of w alone and of r alone (the quadratic form of the
        block's marginal covariance, its minimum over the other block), each at least its squared norm over the
        block's largest eigenvalue, the total covariance taken with the largest loop covariance the graph allows
        (GraphConfig.loop_covariance_bound). Translation: r = V(w)^-1 t_E, where V (SO(3)'s left Jacobian) has no
        singular value above 1, so |r| >= |t_E| = |t_loop - t_odometry| >= |t_odometry| - reach_m. Rotation: |w|
        is the angle between the loop's and the odometry's rotations, at least the angle between the guess's and
        the odometry's less `turn_deg` (the angle between rotations is a metric)."""
        odometry, total = self._drift_covariance(cand, self.settings.graph.loop_covariance_bound())
        gaps = [(float(np.linalg.norm(odometry[:3, 3])) - reach_m, total[3:, 3:])]
        if guess is not None:
            gaps.append((rotation_angle(odometry[:3, :3].T @ guess[:3, :3]) - np.radians(turn_deg), total[:3, :3]))
        bound = chi2_quantile(self.settings.drift_confidence, 6)
        return any(gap > 0 and gap**2 / float(np.linalg.eigvalsh(block)[-1]) > bound for gap, block in gaps)

    def _drift_covariance(self, cand: LoopClosure, loop_covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The odometry T_match_query and the covariance its correction is tested against: drift_gate^2 times the
        odometry covariance accumulated between the keyframes (grown as systematic drift beyond the drift model's
        reference length: drift_chi2), plus `loop_covariance` and the slack."""
        s = self.settings
        odometry, path_cov = self._drift_to(cand.query).between(cand.match, cand.query)
        bound = chi2_quantile(s.drift_confidence, 6)
        slack = np.repeat([np.radians(s.drift_slack_deg), s.drift_slack_m], 3) ** 2 / bound
        # Beyond the calibration length the random walk's variance (growing with the path) becomes systematic
        # drift's (growing with its square), as KITTI's relative error, a constant fraction over 100-800 m, has it
        systematic = max(1.0, cand.travelled_m / s.graph.drift_reference_m) if np.isfinite(cand.travelled_m) else 1.0
        return odometry, s.drift_gate**2 * systematic * path_cov + loop_covariance + np.diag(slack)

    def pr_curve(self) -> PRCurve | None:
        """Precision-recall of the best matches (None when no keyframe had an older one to query)."""
        if not self.best_similarity:
            return None
        return precision_recall(self.best_similarity, self.best_distance, self.settings.loop_radius)


def protocol(settings: LoopSettings) -> str:
    """The loop protocol in force ("auto": paper in oracle mode, verified in realistic mode)."""
    if settings.loop_protocol != "auto":
        return settings.loop_protocol
    return "paper" if settings.mode == "oracle" else "verified"


def acceptance(settings: LoopSettings) -> tuple[float, int]:
    """(similarity floor, candidates a keyframe) of the protocol in force."""
    if protocol(settings) == "paper":
        return settings.similarity_threshold, settings.top_k
    return settings.verified_min_similarity, settings.verified_top_k


def candidate_rule(settings: LoopSettings) -> str:
    """How candidates were chosen, for reports ("similarity >= 0.8" for the paper's protocol on scans)."""
    detector = {"scan": "", "local-map": "local-map "}.get(settings.loop_detector)
    if detector is None:
        return f"MapClosures, best {settings.verified_top_k if protocol(settings) == 'verified' else settings.top_k}"
    threshold, top_k = acceptance(settings)
    if protocol(settings) == "paper":
        return f"{detector}similarity >= {threshold}"
    return f"{detector}similarity >= {threshold}, best {top_k}, verified without an odometry prior"


def drift_check_on(settings: LoopSettings) -> bool:
    """Whether loops are checked against the odometry's drift ("auto": in realistic mode)."""
    return settings.drift_check == "on" or settings.drift_check == "auto" and settings.mode == "realistic"


def loop_summary(
    loops: list[LoopClosure], settings: LoopSettings, graph_info: Mapping[str, JSONValue] | None = None
) -> LoopClosing:
    """What metrics.json reports about loop closing: rejections by reason, accepted loops that are revisits
    (at least 2 x loop_radius of odometry path between the keyframes) apart from the others, and the
    noise models, inlier selection and robust kernel the loop factors had (`graph_info`, the graph's own
    account; without it, what a batch graph in the run's mode does)."""
    accepted = [c for c in loops if c.accepted]
    revisits = sum(c.travelled_m >= 2 * settings.loop_radius for c in accepted)
    graph = settings.graph
    return LoopClosing(
        rejection_counts(loops, REJECTION_REASONS),
        {
            "revisit_loops": int(revisits),
            "other_loops": len(accepted) - int(revisits),
            "min_travel_m": settings.min_travel_m,
            "drift_check": drift_check_on(settings),
            "loop_kernel": graph.loop_kernel(settings.mode),
            "loop_inliers": "consistent" if graph.selects_inliers(settings.mode) else "all",
            **(graph_info or {}),
            "loop_noise": graph.loop_noise,
            "odometry_noise": graph.odometry_noise,
        },
    )
