"""Global place descriptors: Scan Context, OverlapTransformer (optional torch), precomputed arrays."""

from msa_slam.descriptors.base import Descriptor
from msa_slam.descriptors.precomputed import PrecomputedDescriptors
from msa_slam.descriptors.registry import DESCRIPTOR_NAMES, make_descriptor
from msa_slam.descriptors.scan_context import ScanContext

__all__ = ["DESCRIPTOR_NAMES", "Descriptor", "PrecomputedDescriptors", "ScanContext", "make_descriptor"]
