"""Keyframe samplers: MSA (the paper's method) and its baselines, behind one push/finish API."""

from msa_slam._lazy import lazy_exports

_EXPORTS = {
    "Sampler": "base",
    "SamplerStats": "base",
    "AllSamples": "baselines",
    "ConstantDistance": "baselines",
    "Entropy": "baselines",
    "Spaciousness": "baselines",
    "MSASampler": "msa.sampler",
    "SamplerParams": "params",
    "SAMPLERS": "registry",
    "SamplerChoice": "registry",
    "build_sampler": "registry",
    "check_sampler_params": "registry",
    "make_sampler": "registry",
    "sampler_parameters": "registry",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
