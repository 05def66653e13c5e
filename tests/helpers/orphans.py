"""The background side of the orphan test in test_trust_inputs: a spawned process that ends with its parent by
warm's portable fallback alone (the thread watching the parent), as on a system without prctl."""

from __future__ import annotations

import signal
from pathlib import Path

from msa_slam.sampling.msa import warm


def fallback_child(parent: int, ready: str) -> None:
    """Set up warm's end-with-parent without prctl, say so by creating the file `ready`, then wait to be ended."""
    warm._kill_on_parent_death = lambda: False  # as where prctl is absent
    warm._PARENT_POLL_S = 0.05
    warm._end_with_parent(parent)
    Path(ready).touch()
    while True:
        signal.pause()
