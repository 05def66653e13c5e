"""Samplers by name, for configs and the CLI, with parameters validated against each constructor."""

from __future__ import annotations

import inspect
from typing import Any

from msa_slam.errors import InputError
from msa_slam.sampling.base import Sampler
from msa_slam.sampling.baselines import AllSamples, ConstantDistance, Entropy, Spaciousness
from msa_slam.sampling.msa.sampler import MSASampler

SAMPLERS: dict[str, type[Sampler]] = {
    "all": AllSamples,
    "constant": ConstantDistance,
    "entropy": Entropy,
    "spaciousness": Spaciousness,
    "msa": MSASampler,
}


def sampler_parameters(name: str) -> dict[str, Any]:
    """Parameter names and defaults of a registered sampler."""
    cls = _lookup(name)
    sig = inspect.signature(cls.__init__)
    return {p.name: p.default for p in list(sig.parameters.values())[1:]}


def make_sampler(name: str, **params: Any) -> Sampler:
    """Build a sampler by name; unknown names or parameters raise InputError listing what exists."""
    cls = _lookup(name)
    known = sampler_parameters(name)
    unknown = sorted(set(params) - set(known))
    if unknown:
        listing = ", ".join(f"{k}={v!r}" for k, v in known.items()) or "(none)"
        raise InputError(f"sampler {name!r}: unknown parameter(s) {', '.join(unknown)}; "
                         f"it takes: {listing}")
    return cls(**params)  # each constructor checks its values (sampling/checks.py) and names the bad one


def _lookup(name: str) -> type[Sampler]:
    try:
        return SAMPLERS[name]
    except KeyError:
        raise InputError(f"unknown sampler {name!r}; available: {', '.join(SAMPLERS)}") from None
