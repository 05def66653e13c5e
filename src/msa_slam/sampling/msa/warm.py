"""Compile MSA's numba kernels in a background process while a long job's first stages keep one core busy.

numba compiles a kernel on its first call (about a minute of CPU for the kernels MSA's default mode uses, on
this project's 2-core machine) and keeps the machine code in its on-disk cache (the kernels use cache=True).
A cold front end (pipeline.frontend, for `run`, `compare` and the demo) spends minutes running KISS-ICP on one
core, so the other core can compile meanwhile; MSA's first window then loads the cache instead of compiling. The compiled code, and so every result, is the same either way; if the background process
cannot start, or has not finished in time, MSA compiles the kernels itself as before.
"""

from __future__ import annotations

import multiprocessing
import os
import warnings
from collections.abc import Mapping
from multiprocessing.process import BaseProcess
from typing import Any

import numpy as np

from msa_slam.lifetime import end_with_parent

_FRAMES = 40  # enough for several full windows at the default N = 10
_LOADED: set[tuple[str, tuple[int, ...]]] = set()  # settings whose kernels this process has already loaded


def compile_kernels(params: dict[str, Any], shape: tuple[int, ...]) -> None:
    """Run MSA with `params` on a short synthetic stream of descriptors of `shape` (a straight drive at
    ~1 m per frame), so that every kernel those settings use is compiled and cached. Its warnings (the
    settings' bounds may not suit this stream) are not the user's data's, and are dropped."""
    from msa_slam.sampling import make_sampler

    rng = np.random.default_rng(0)
    poses = np.tile(np.eye(4), (_FRAMES, 1, 1))
    poses[:, 0, 3] = np.cumsum(rng.uniform(0.6, 1.4, _FRAMES))
    descriptors = np.abs(np.cumsum(rng.standard_normal((_FRAMES, *shape)), axis=0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        make_sampler("msa", **params).run(poses, descriptors)


def load_kernels(sampler: str, params: Mapping[str, Any], shape: tuple[int, ...]) -> None:
    """Before a timed run with `sampler`: load (compile when not cached) MSA's kernels for these settings, a
    one-time cost of the process (~58 MiB RSS, 0.25 s from numba's cache, about a minute of CPU to compile)
    that would otherwise land in the run's sampling time, throughput and RSS growth (simulated KITTI-00,
    600 frames: 77 MiB of growth instead of 22 MiB, against 15.5 MiB accounted). Other samplers need none.
    Each setting is loaded once per process: the synthetic run costs seconds in exact mode at N = 16, which an
    experiment grid would otherwise pay again for every cell with the same settings."""
    if sampler != "msa":
        return
    key = (repr(sorted(params.items())), tuple(shape))
    if key not in _LOADED:
        compile_kernels(dict(params), tuple(shape))
        _LOADED.add(key)


def _compile_at_low_priority(parent: int, params: dict[str, Any], shape: tuple[int, ...]) -> None:
    """compile_kernels at the lowest CPU priority, ending with `parent` (the process that started it): the
    simulator's workers come first, the compilation takes the core KISS-ICP leaves free."""
    end_with_parent(parent)
    if hasattr(os, "nice"):
        os.nice(19)
    compile_kernels(params, shape)


def compile_in_background(params: dict[str, Any], shape: tuple[int, ...]) -> BaseProcess | None:
    """Start compile_kernels in a spawned daemon process at low priority, ended with the caller however the
    caller ends (msa_slam.lifetime.end_with_parent); None when it cannot start (a daemonic process, such as a
    Dask or pool worker, may not have children: the kernels then compile on first use, as without this)."""
    if multiprocessing.current_process().daemon:
        return None
    try:
        process = multiprocessing.get_context("spawn").Process(
            target=_compile_at_low_priority,
            args=(os.getpid(), dict(params), tuple(shape)),
            daemon=True,
            name="msa-compile",
        )
        process.start()
    except OSError:
        return None
    return process
