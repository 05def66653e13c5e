"""Pose-graph back-end on GTSAM: batch Levenberg-Marquardt and incremental iSAM2 with one interface."""

from msa_slam.backend.graph import IncrementalPoseGraph, PoseGraph
from msa_slam.backend.graph_config import GraphConfig

__all__ = ["GraphConfig", "IncrementalPoseGraph", "PoseGraph"]
