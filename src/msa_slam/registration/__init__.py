"""Loop verification (small_gicp GICP with a residual gate) and the downsampled keyframe-cloud store."""

from msa_slam.registration.clouds import KeyframeCloudStore, as_points, downsample
from msa_slam.registration.verify import Verification, Verifier, VerifierConfig

__all__ = ["KeyframeCloudStore", "Verification", "Verifier", "VerifierConfig", "as_points", "downsample"]
