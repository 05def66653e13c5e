"""Samplers by name, for configs and the CLI: each sampler's class and its typed parameters (the tagged union a
run's configuration holds, the sampler's name its tag)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any

from pydantic import Field

from msa_slam.errors import InputError
from msa_slam.sampling.base import Sampler
from msa_slam.sampling.baselines import (
    AllParams,
    AllSamples,
    ConstantDistance,
    ConstantParams,
    Entropy,
    EntropyParams,
    Spaciousness,
    SpaciousnessParams,
)
from msa_slam.sampling.msa.params import MSAParams
from msa_slam.sampling.msa.sampler import MSASampler
from msa_slam.sampling.params import TAG, SamplerParams, check_params

SAMPLERS: dict[str, type[Sampler]] = {
    "all": AllSamples,
    "constant": ConstantDistance,
    "entropy": Entropy,
    "spaciousness": Spaciousness,
    "msa": MSASampler,
}
# A sampler and its parameters in one value: pydantic picks the model by the `sampler` tag (tests check that it
# holds every sampler's Params)
SamplerChoice = Annotated[
    AllParams | ConstantParams | EntropyParams | SpaciousnessParams | MSAParams, Field(discriminator=TAG)
]


def sampler_parameters(name: str) -> dict[str, Any]:
    """Parameter names and defaults of a registered sampler (its own first, then the standstill gate's)."""
    return _lookup(name).Params.defaults()


def check_sampler_params(name: str, params: Mapping[str, Any]) -> SamplerParams:
    """`params` validated as sampler `name`'s, without building it; InputError naming the bad key."""
    return check_params(_lookup(name).Params, params)


def make_sampler(name: str, **params: Any) -> Sampler:
    """Build a sampler by name; unknown names or parameters raise InputError listing what exists."""
    return _lookup(name)(**params)


def build_sampler(params: SamplerParams) -> Sampler:
    """The sampler of parameters a configuration already validated."""
    return SAMPLERS[params.NAME](params)


def _lookup(name: str) -> type[Sampler]:
    try:
        return SAMPLERS[name]
    except (KeyError, TypeError):
        raise InputError(f"unknown sampler {name!r}; available: {', '.join(SAMPLERS)}") from None
