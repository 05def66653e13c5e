"""The SLAM core built from a run's configuration: its sampler with the standstill gate, its loop closer and the
back end around them. Kept apart from the per-frame core (slam.backend) so that what a run is made of is decided in
one place, and `build_backend` takes the sampler and loop closer as arguments (a replay or a test passes its own)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from msa_slam.descriptors import Descriptor
from msa_slam.registration import Verifier
from msa_slam.registration.cloud_cache import CloudsByFrame
from msa_slam.sampling.base import Sampler
from msa_slam.sampling.params import GATE_PARAMETERS
from msa_slam.sampling.registry import build_sampler
from msa_slam.slam.backend import Graph, Recorder, SlamBackend
from msa_slam.slam.keyframes import CloudStore, KeyframeStore
from msa_slam.slam.local_map import LocalMap
from msa_slam.slam.loop_closing import LoopCloser
from msa_slam.slam.map_closures_detector import MapClosuresDetector
from msa_slam.slam.result import RunSettings

# The standstill gate the SLAM core gives every sampler but "all" (sampling/base.py; docs/msa.md, "Standing still"):
# a frame that moved < 0.1 m and turned < 0.5 deg since the last frame passed on is no keyframe candidate. KISS-ICP
# at a standstill on simulated KITTI-like scans jitters up to 5.2 cm and 0.115 deg (1,000 frames, three places), and
# 0.1 m is also KISS-ICP's own min_motion_th, below which it takes a frame as not moving. A run's sampler_params
# override either value (min_motion=0 gives the reference's behaviour).
STANDSTILL_GATE = {"min_motion": 0.1, "min_rotation": 0.5}
UNGATED_SAMPLERS = ("all",)  # every frame by definition: the paper's upper bound on memory and loop candidates


def slam_sampler_params(sampler: str, params: Mapping[str, Any]) -> dict[str, Any]:
    """The parameters the SLAM core builds `sampler` with: STANDSTILL_GATE under the run's own `params`, except
    for UNGATED_SAMPLERS. The gate lives here rather than in the samplers' defaults because make_sampler's
    defaults are the reference's behaviour (the parity tests' API) and SLAM is where frames that do not move
    cost memory (keyframe clouds, descriptors, graph nodes), as KISS-ICP and KISS-SLAM skip them."""
    if sampler in UNGATED_SAMPLERS:
        return dict(params)
    merged = {**STANDSTILL_GATE, **params}
    if merged["min_motion"] == 0 and "min_rotation" not in params:  # -p min_motion=0 switches the whole gate off
        merged["min_rotation"] = 0.0
    return merged


def slam_sampler(config: RunSettings) -> Sampler:
    """The run's sampler, from the parameters its config validated, with the SLAM core's standstill gate
    (slam_sampler_params)."""
    gated = slam_sampler_params(config.sampler, config.sampler_params)
    return build_sampler(
        config.sampler_params.model_copy(update={k: float(gated[k]) for k in GATE_PARAMETERS if k in gated})
    )


def build_loop_closer(config: RunSettings, descriptor: Descriptor, clouds: CloudStore) -> LoopCloser:
    """Loop closing for a run configuration: a keyframe store over `clouds` whose descriptor is the frames'
    (`descriptor`) or, with the local-map detector, Scan Context of the local maps; the verifier; MapClosures for
    the map-closures detector."""
    loop_descriptor = local_map_descriptor(config) if config.loop_detector == "local-map" else None
    store = KeyframeStore(loop_descriptor or descriptor, clouds)
    map_closures = MapClosuresDetector() if config.loop_detector == "map-closures" else None
    return LoopCloser(store, Verifier(config.verifier), config, map_closures)


def build_backend(
    config: RunSettings,
    sampler: Sampler,
    loop_closer: LoopCloser,
    graph: Graph,
    n_frames: int,
    name: str,
    update_iterations: int = 0,
    recorder: Recorder | None = None,
    frame_clouds: CloudsByFrame | None = None,
    local_maps: bool = True,
) -> SlamBackend:
    """The SLAM core for a run configuration (msa_slam.pipeline.config.RunConfig) around its `sampler`
    (slam_sampler) and `loop_closer` (build_loop_closer, whose store is filled from `frame_clouds` when given,
    which must be downsampled at the verifier's voxel size) and `graph` (batch LM or iSAM2). The local-map and
    map-closures detectors keep a local map of the recent scans, unless `local_maps` is False (the store's clouds
    are the keyframes' local maps already: a replay)."""
    if frame_clouds is not None and frame_clouds.voxel_size != config.verifier.voxel_size:
        raise ValueError(
            f"frame clouds downsampled at {frame_clouds.voxel_size} m for a run whose verifier uses "
            f"{config.verifier.voxel_size} m voxels"
        )
    detector = config.loop_detector
    local_map = LocalMap(config.local_map_m, config.verifier.voxel_size) if local_maps and detector != "scan" else None
    loop_descriptor = loop_closer.store.descriptor if detector == "local-map" else None
    return SlamBackend(
        config,
        sampler,
        loop_closer.store,
        loop_closer,
        graph,
        n_frames,
        name,
        update_iterations,
        recorder,
        local_map,
        loop_descriptor,
        frame_clouds,
    )


def local_map_descriptor(config: RunSettings) -> Descriptor:
    """Scan Context for local maps: the run's own Scan Context parameters when its descriptor is Scan Context,
    else the authors' configuration."""
    from msa_slam.descriptors.scan_context import ScanContext

    params = config.descriptor_params if str(config.descriptor).lower() in ("sc", "scan_context") else {}
    return ScanContext(**params)
