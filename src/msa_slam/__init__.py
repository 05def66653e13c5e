"""msa-slam: informed keyframe sampling (Minimal Subset Approach) for large-scale LiDAR SLAM."""

__version__ = "0.1.0"
