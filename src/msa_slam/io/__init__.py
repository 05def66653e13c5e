"""File formats: pose files (KITTI, TUM), atomic writes."""
