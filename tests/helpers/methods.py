"""A comparison's method made to misbehave: compare's run (pipeline.driver.run) patched for one method (compare's worker
processes inherit the patch by fork)."""

from __future__ import annotations

from collections.abc import Callable

import pytest

import msa_slam.experiments.compare as compare


def before_method(monkeypatch: pytest.MonkeyPatch, name: str, action: Callable[[], None]) -> None:
    """Call `action` (raise, die) when the method `name` starts, then run it as usual."""
    real = compare.run

    def patched(cfg, *args, **kwargs):
        if cfg.name == name:
            action()
        return real(cfg, *args, **kwargs)

    monkeypatch.setattr(compare, "run", patched)


def degenerate() -> None:
    """A method's failure at run time."""
    raise RuntimeError("degenerate scan statistics")
