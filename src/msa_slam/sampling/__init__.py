"""Keyframe samplers: MSA (the paper's method) and its baselines, behind one push/finish API."""

from msa_slam.sampling.base import Sampler, SamplerStats
from msa_slam.sampling.baselines import AllSamples, ConstantDistance, Entropy, Spaciousness
from msa_slam.sampling.msa import MSASampler
from msa_slam.sampling.registry import SAMPLERS, make_sampler, sampler_parameters

__all__ = [
    "Sampler", "SamplerStats", "AllSamples", "ConstantDistance", "Entropy", "Spaciousness",
    "MSASampler", "SAMPLERS", "make_sampler", "sampler_parameters",
]
