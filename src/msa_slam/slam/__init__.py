"""The per-frame SLAM core shared by the batch and online pipelines: keyframe store, loop closing and the
back-end driver (add_frame -> new keyframes; finish -> RunResult)."""

from msa_slam.slam.backend import BACKEND_STEPS, SlamBackend
from msa_slam.slam.build import build_backend, build_loop_closer, slam_sampler
from msa_slam.slam.keyframes import KeyframeStore
from msa_slam.slam.loop_closing import LoopCloser
from msa_slam.slam.measure import measure
from msa_slam.slam.result import RunResult
from msa_slam.types import LoopClosure

__all__ = [
    "BACKEND_STEPS",
    "KeyframeStore",
    "LoopCloser",
    "LoopClosure",
    "RunResult",
    "SlamBackend",
    "build_backend",
    "build_loop_closer",
    "measure",
    "slam_sampler",
]
