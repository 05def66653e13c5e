"""Loop verification (small_gicp GICP with a residual gate) and the downsampled keyframe-cloud stores
(in memory, or on disk for long runs)."""

from msa_slam.registration.clouds import KeyframeCloudStore, as_points, downsample
from msa_slam.registration.disk_store import DiskCloudStore, make_cloud_store
from msa_slam.registration.verify import Verification, Verifier, VerifierConfig

__all__ = [
    "DiskCloudStore",
    "KeyframeCloudStore",
    "Verification",
    "Verifier",
    "VerifierConfig",
    "as_points",
    "downsample",
    "make_cloud_store",
]
