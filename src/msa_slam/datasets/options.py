"""What of a recording a run reads (the `source` section of a run's configuration, set by --topic, --gt,
--sequence, --first, --jump and -n)."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from msa_slam.config import StageConfig


class SourceOptions(StageConfig):
    """`topic`: a bag's PointCloud2 topic; `gt`: a LiDAR-frame pose file (KITTI or TUM, `gt_format`) used as
    ground truth; `sequence`: a sequence of a dataset root (HeLiPR: the sensor); every `jump`-th scan from
    scan `first`, at most `frames` of them."""

    SECTION: ClassVar[str] = "source"

    topic: str | None = None
    gt: str | None = None
    gt_format: Literal["auto", "kitti", "tum"] = "auto"
    sequence: str | None = None
    first: int = Field(0, ge=0)
    jump: int = Field(1, ge=1)
    frames: int | None = Field(None, ge=1)
