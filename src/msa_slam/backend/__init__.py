"""Pose-graph back-end on GTSAM: batch Levenberg-Marquardt and incremental iSAM2 with one interface."""

from msa_slam.backend.graph import GraphConfig, IncrementalPoseGraph, PoseGraph

__all__ = ["GraphConfig", "IncrementalPoseGraph", "PoseGraph"]
