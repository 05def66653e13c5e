"""OverlapTransformer descriptor (Ma, Zhang, Xu, Ai, Gu, Chen; RA-L 2022) with the authors' weights.

Optional: needs torch (`pip install msa-slam[ot]`) and a checkpoint path given by the user (a torch
file whose 'state_dict' holds the weights). Range projection in `range_image`, network in
`_ot_network`. Similarity 1/(1 + L2), as the MSA paper uses it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from msa_slam.descriptors.base import validate_bank
from msa_slam.descriptors.range_image import range_projection
from msa_slam.errors import InputError

DESCRIPTOR_DIM = 256
# Present in the authors' checkpoint, not used at inference (batch norms and the unused heads).
_UNUSED_PREFIXES = ("bn", "linear.", "linear1.", "linear2.", "linear3.", "net_vlad.bn2.")


def _import_torch():
    try:
        import torch
    except ImportError as exc:
        raise InputError(
            "overlap_transformer: torch is not installed; install the extra with `pip install msa-slam[ot]`"
        ) from exc
    return torch


def load_network(weights: str | Path):
    """OverlapTransformer network in eval mode with the checkpoint's weights; InputError on any mismatch."""
    torch = _import_torch()
    from msa_slam.descriptors._ot_network import OverlapTransformerNet

    path = Path(weights)
    if not path.is_file():
        raise InputError(f"overlap_transformer: weights file not found: {path}")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for unreadable files
        raise InputError(f"overlap_transformer: cannot read weights file {path}: {exc}") from exc
    state = checkpoint.get("state_dict", checkpoint) if isinstance(checkpoint, dict) else None
    if not isinstance(state, dict):
        raise InputError(f"overlap_transformer: {path} holds no 'state_dict' mapping")
    net = OverlapTransformerNet()
    wanted = net.state_dict()
    missing = [name for name in wanted if name not in state]
    if missing:
        raise InputError(f"overlap_transformer: {path} lacks weights used at inference: {', '.join(missing[:5])}")
    for name, tensor in wanted.items():
        got = tuple(state[name].shape)
        if got != tuple(tensor.shape):
            raise InputError(
                f"overlap_transformer: {path}: '{name}' has shape {got}, expected {tuple(tensor.shape)}"
            )
    unknown = [n for n in state if n not in wanted and not n.startswith(_UNUSED_PREFIXES)]
    if unknown:
        raise InputError(f"overlap_transformer: {path} has unexpected weights: {', '.join(unknown[:5])}")
    net.load_state_dict({name: state[name] for name in wanted})
    return net.eval()


class OverlapTransformer:
    """Learned yaw-invariant 256-d descriptor; `weights` is the path to the authors' checkpoint."""

    name = "overlap_transformer"
    shape = (DESCRIPTOR_DIM,)

    def __init__(self, weights: str | Path, max_range: float = 80.0) -> None:
        self.max_range = float(max_range)
        self.network = load_network(weights)
        self._torch = _import_torch()

    def descriptors_from_range_images(self, images: np.ndarray) -> np.ndarray:
        """(B, 256) float32 descriptors of (B, 64, 900) range images."""
        images = np.asarray(images, dtype=np.float32)
        if images.ndim != 3 or images.shape[1:] != (64, 900):
            raise InputError(f"overlap_transformer: expected range images (B, 64, 900), got {images.shape}")
        with self._torch.inference_mode():
            out = self.network(self._torch.from_numpy(np.ascontiguousarray(images))[:, None])
        return out.numpy().astype(np.float32)

    def compute(self, points: np.ndarray | None, frame: int | None = None) -> np.ndarray:
        """(256,) descriptor of a raw scan (authors' range projection, then the network)."""
        image = range_projection(points, max_range=self.max_range)
        return self.descriptors_from_range_images(image[None])[0]

    def similarity_many(self, query: np.ndarray, bank: np.ndarray) -> np.ndarray:
        """1 / (1 + ||query - d||) for each stored descriptor d."""
        bank = validate_bank(bank, self.shape, "overlap_transformer bank")
        q = validate_bank(np.asarray(query)[None], self.shape, "overlap_transformer query")[0]
        return 1.0 / (1.0 + np.linalg.norm(bank - q, axis=1))

    def similarity(self, a: np.ndarray, b: np.ndarray) -> float:
        """1 / (1 + ||a - b||)."""
        return float(self.similarity_many(a, np.asarray(b)[None])[0])
