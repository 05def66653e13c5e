"""Build a descriptor from its name, as configs and the CLI name them.

Classes are imported on demand so that torch is only needed when OverlapTransformer is asked for.
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any

from msa_slam.descriptors.base import Descriptor
from msa_slam.errors import InputError

_CLASSES: dict[str, tuple[str, str]] = {
    "sc": ("msa_slam.descriptors.scan_context", "ScanContext"),
    "scan_context": ("msa_slam.descriptors.scan_context", "ScanContext"),
    "ot": ("msa_slam.descriptors.overlap_transformer", "OverlapTransformer"),
    "overlap_transformer": ("msa_slam.descriptors.overlap_transformer", "OverlapTransformer"),
    "precomputed": ("msa_slam.descriptors.precomputed", "PrecomputedDescriptors"),
}
DESCRIPTOR_NAMES = tuple(_CLASSES)


def make_descriptor(name: str, **params: Any) -> Descriptor:
    """Descriptor by name: "sc"/"scan_context", "ot"/"overlap_transformer" (weights=path), "precomputed" (path=...)."""
    entry = _CLASSES.get(str(name).lower())
    if entry is None:
        raise InputError(f"descriptor: unknown name {name!r}; choose one of {', '.join(DESCRIPTOR_NAMES)}")
    module = importlib.import_module(entry[0])
    cls = getattr(module, entry[1])
    try:
        inspect.signature(cls).bind(**params)
    except TypeError as exc:
        hint = f"; it needs {module.WEIGHTS_HINT}" if "weights" in str(exc) and hasattr(module, "WEIGHTS_HINT") else ""
        raise InputError(f"descriptor {name!r}: bad parameters {sorted(params)}: {exc}{hint}") from exc
    return cls(**params)
