"""Which odometry a run uses and whether it deskews, decided once from the run's settings and whether its scans
carry per-point times, before any cache key is made: the batch and live front ends, cached and fresh, then
record and key what is done. It imports nothing outside odometry/ and the scan readers, which the odometry cache's
key fingerprints (odometry.cache.ODOMETRY_CODE)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

import numpy as np

from msa_slam.datasets.options import SourceOptions
from msa_slam.errors import InputError
from msa_slam.odometry.kiss import PARAMETERS as KISS_PARAMETERS
from msa_slam.odometry.kiss import KissOdometry, PosesFromFile


class OdometrySettings(Protocol):
    """The part of a run's configuration (pipeline.config.RunConfig) the odometry depends on."""

    @property
    def odometry(self) -> str: ...  # "kiss" or a pose file
    @property
    def odometry_params(self) -> dict[str, Any]: ...
    @property
    def source(self) -> SourceOptions: ...  # the scans read (first, jump)


def make_odometry(
    config: OdometrySettings, n_frames: int, point_times: bool | None = True
) -> KissOdometry | PosesFromFile:
    """KISS-ICP with `odometry_params`, or the pose file named by `config.odometry`: one pose a scan of the
    recording, cut by the same --first/--jump/-n as the scans (a file with one pose a selected scan is
    taken as it is).

    KISS-ICP deskews when the scans carry per-point times (`point_times` True), as kiss-icp does, unless
    `odometry.deskew=false`; without them (False), or when the source does not say (None), it does not. A
    deskew asked for scans without per-point times is switched off here with one warning (deskew_dropped)."""
    if config.odometry == "kiss":
        try:  # deskew_choice's default unless odometry_params say (an asked deskew dropped below)
            odometry = KissOdometry(**{"deskew": deskew_choice(config, point_times)[0], **config.odometry_params})
        except TypeError as exc:
            raise InputError(
                f"odometry kiss: bad parameters {sorted(config.odometry_params)} ({exc}); "
                f"it takes {', '.join(KISS_PARAMETERS)}"
            ) from None
        if deskew_dropped(config, point_times):
            odometry.without_point_times()
        return odometry
    if config.odometry_params:
        raise InputError(f"odometry from a pose file takes no parameters, got {sorted(config.odometry_params)}")
    path = Path(config.odometry).expanduser()
    if not path.is_file():
        raise InputError(f"odometry {config.odometry!r}: neither 'kiss' nor an existing pose file")
    from_file = PosesFromFile(path)
    if len(from_file) == n_frames:
        return from_file
    rows = config.source.first + config.source.jump * np.arange(n_frames)
    if len(from_file) <= rows[-1]:
        selection = (
            f" (scans {rows[0]}, {rows[0] + config.source.jump}, ... {rows[-1]} of the recording)"
            if n_frames > 1
            else ""
        )
        raise InputError(
            f"odometry pose file {path}: {len(from_file)} poses but the run reads {n_frames} scans"
            f"{selection}; give one pose a scan of the recording, or one a scan read"
        )
    from_file.select(rows)
    return from_file


def deskew_dropped(config: OdometrySettings, point_times: bool | None) -> bool:
    """Whether `config` asks KISS-ICP to deskew scans that have no per-point times (`point_times` False), which
    make_odometry then switches off."""
    return config.odometry == "kiss" and point_times is False and config.odometry_params.get("deskew") is True


def deskew_choice(config: OdometrySettings, point_times: bool | None) -> tuple[bool | None, str]:
    """(whether the odometry deskews, why) for scans with per-point times (`point_times` True), without (False)
    or not known (None); None for an odometry other than KISS-ICP. Off by default without per-point times, as
    there is nothing to deskew with; an explicit odometry.deskew wins where it can be done."""
    if config.odometry != "kiss":
        return None, "odometry is not KISS-ICP"
    asked = config.odometry_params.get("deskew")
    if deskew_dropped(config, point_times):
        return False, "no per-point times (odometry.deskew=true dropped)"
    if asked is not None:
        return bool(asked), f"odometry.deskew={str(bool(asked)).lower()}"
    return (True, "per-point times") if point_times else (False, "no per-point times")
