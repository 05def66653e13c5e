"""A sampler over a stream given as files (`msa-slam sample`): poses, and descriptors or scans when the sampler
needs them; keyframes written to a result folder without any SLAM around the sampler."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from msa_slam import __version__
from msa_slam.datasets import check_scan_folder
from msa_slam.datasets.sequences import load_cloud_stack
from msa_slam.descriptors.precomputed import load_descriptor_file
from msa_slam.errors import InputError
from msa_slam.io.outputs import DEFAULT_RESULTS, open_result_folder
from msa_slam.io.poses import read_poses
from msa_slam.progress import progress_bar
from msa_slam.sampling import figure
from msa_slam.sampling.msa.warm import load_kernels
from msa_slam.sampling.registry import make_sampler, sampler_parameters


def sample_files(
    poses: Path,
    descriptors: Path | None,
    clouds: Path | None,
    sampler: str,
    params: dict[str, Any],
    pose_format: str = "auto",
    out: str | os.PathLike | None = None,
    overwrite: bool = False,
    flush: bool = False,
    quiet: bool = True,
) -> tuple[Path, int, int]:
    """Run `sampler` with `params` over the poses (and per-frame `descriptors` .npy, scan folder or .npy `clouds`)
    and write keyframes.txt, keyframes.json and keyframes.png into the result folder `out` (checked before the
    sampler runs; None: a new one under msa_slam_results/sample); `flush`: the last window flushed at the end
    (reported apart). Returns the folder, the keyframes and the frames."""
    chosen = make_sampler(sampler, **params)
    pose_stack, _ = read_poses(poses, pose_format)  # read_poses checks TUM times; sampling does not use them
    n = len(pose_stack)
    desc = load_descriptor_file(descriptors, n) if descriptors is not None else None
    if desc is None and chosen.needs_descriptors:
        raise InputError(f"sampler {sampler!r} needs --descriptors (an .npy array with one descriptor per pose)")
    if clouds is not None and clouds.suffix != ".npy":
        check_scan_folder(clouds, sequence_option=False)
    cloud_list = load_cloud_stack(clouds, n) if clouds is not None else None
    if cloud_list is None and chosen.needs_points:
        raise InputError(f"sampler {sampler!r} needs --clouds (a folder of scans or an .npy array)")
    chosen.expect_frames(n, flush)  # its warning (a window longer than the stream) after the errors above
    if desc is not None:  # compiled before the first window, not inside its optimisation_ms
        load_kernels(sampler, params, desc.shape[1:])

    with open_result_folder(out, "sample", DEFAULT_RESULTS / "sample", overwrite=overwrite) as folder:
        with progress_bar(quiet, transient=False) as progress:
            task = progress.add_task(f"sampling ({sampler})", total=n)
            for i in range(n):
                chosen.push(
                    pose_stack[i], None if desc is None else desc[i], None if cloud_list is None else cloud_list[i]
                )
                progress.advance(task)
        flushed = chosen.finish() if flush else []
        keyframes = chosen.keyframes
        record = {
            "version": __version__,
            "sampler": sampler,
            "params": {**sampler_parameters(sampler), **params},
            "inputs": {
                "poses": str(poses),
                "descriptors": str(descriptors) if descriptors else None,
                "clouds": str(clouds) if clouds else None,
            },
            "frames": n,
            "keyframes": keyframes,
            "online_keyframes": chosen.online_keyframes,
            "flushed_keyframes": flushed,
            "stats": chosen.stats.as_dict(),
        }
        with folder.staging() as tmp:  # the three files appear together or not at all
            (tmp / "keyframes.txt").write_text("".join(f"{k}\n" for k in keyframes))
            (tmp / "keyframes.json").write_text(json.dumps(record, indent=2) + "\n")
            figure.plot_keyframes(
                pose_stack,
                keyframes,
                tmp / "keyframes.png",
                title=f"{sampler}: {len(keyframes)} of {n} frames",
                flushed=flushed,
            )
    return folder.path, len(keyframes), n
