"""provenance.json: what produced a result folder (msa-slam and library versions, command line, date, CPU,
Python, OS), so a number can be traced to the software and machine behind it. Volatile by nature."""

from __future__ import annotations

import os
import platform
import sys
from datetime import datetime, timezone
from typing import Any

import msa_slam
from msa_slam.io.cache import library_versions

# The distributions whose versions change results (odometry, registration, graph, evaluation, figures).
LIBRARIES = (
    "numpy",
    "scipy",
    "numba",
    "gtsam",
    "kiss-icp",
    "small_gicp",
    "evo",
    "open3d",
    "torch",
    "matplotlib",
    "pydantic",
    "rosbags",
    "rerun-sdk",
)


def cpu_model() -> str:
    """The CPU's model name (Linux /proc/cpuinfo; platform's processor string elsewhere)."""
    try:
        with open("/proc/cpuinfo") as handle:
            for line in handle:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def provenance() -> dict[str, Any]:
    """The provenance record of this process, now."""
    return {
        "msa_slam_version": msa_slam.__version__,
        "command_line": [sys.argv[0].rsplit("/", 1)[-1], *sys.argv[1:]],
        "date_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "libraries": library_versions(LIBRARIES),
    }
