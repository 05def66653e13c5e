"""Pose-graph back-end on GTSAM: batch Levenberg-Marquardt and incremental iSAM2 with one interface."""

from msa_slam.backend.graph import GraphNoise, IncrementalPoseGraph, PoseGraph

__all__ = ["GraphNoise", "IncrementalPoseGraph", "PoseGraph"]
