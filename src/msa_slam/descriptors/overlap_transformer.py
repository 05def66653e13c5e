"""OverlapTransformer descriptor (Ma, Zhang, Xu, Ai, Gu, Chen; RA-L 2022) with the authors' weights.

Optional: needs torch (`pip install msa-slam[ot]`) and the authors' pretrained weights, which they publish
(GPL-3.0, github.com/haomo-ai/OverlapTransformer, "model pretrained on KITTI") as
pretrained_overlap_transformer.pth.tar at WEIGHTS_URL; pass the file as `--descriptor ot -p
weights=FILE`. Accepted: that checkpoint as published (a dict whose 'state_dict' holds the
weights) or a plain state_dict (`convert_checkpoint` writes one). Range projection in `range_image`, network
in `_ot_network`. Similarity 1/(1 + L2), as the MSA paper uses it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from msa_slam.descriptors.base import scan_points, validate_bank
from msa_slam.descriptors.range_image import range_projection
from msa_slam.errors import InputError

DESCRIPTOR_DIM = 256
WEIGHTS_URL = "https://drive.google.com/file/d/1FNrx9pcDa9NF7z8CFtuTWyauNkeSEFW4/view?usp=sharing"
WEIGHTS_HINT = (
    f"the authors' pretrained_overlap_transformer.pth.tar ({WEIGHTS_URL}, linked from "
    "github.com/haomo-ai/OverlapTransformer), given as --descriptor ot -p weights=FILE"
)
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


def state_dict_of(checkpoint: object, path: Path) -> dict:
    """The weights in a loaded checkpoint: its 'state_dict' (the authors' checkpoint as published) or the
    mapping itself (a plain state_dict); a 'module.' prefix (saved from DataParallel) is dropped."""
    state = checkpoint.get("state_dict", checkpoint) if isinstance(checkpoint, dict) else None
    if not isinstance(state, dict) or not state or not all(isinstance(k, str) for k in state):
        found = type(checkpoint).__name__ if not isinstance(checkpoint, dict) else f"keys {sorted(checkpoint)[:5]}"
        raise InputError(
            f"overlap_transformer: {path} is not an OverlapTransformer checkpoint (a dict with a "
            f"'state_dict', or a state_dict); it holds {found}. Expected {WEIGHTS_HINT}"
        )
    if all(k.startswith("module.") for k in state):
        state = {k[len("module.") :]: v for k, v in state.items()}
    return state


def read_checkpoint(weights: str | Path) -> dict:
    """The state_dict of a weights file (see state_dict_of), loaded without running pickled code."""
    torch = _import_torch()
    path = Path(weights)
    if not path.is_file():
        raise InputError(f"overlap_transformer: weights file not found: {path}; expected {WEIGHTS_HINT}")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for unreadable files
        raise InputError(
            f"overlap_transformer: cannot read weights file {path} as a torch checkpoint: {exc}; "
            f"expected {WEIGHTS_HINT}"
        ) from exc
    return state_dict_of(checkpoint, path)


def load_network(weights: str | Path):
    """OverlapTransformer network in eval mode with the checkpoint's weights; InputError on any mismatch."""
    path = Path(weights)
    state = read_checkpoint(path)  # first: without torch, its clear error comes before the network's import
    from msa_slam.descriptors._ot_network import OverlapTransformerNet

    net = OverlapTransformerNet()
    wanted = net.state_dict()
    missing = [name for name in wanted if name not in state]
    if missing:
        raise InputError(f"overlap_transformer: {path} lacks weights used at inference: {', '.join(missing[:5])}")
    for name, tensor in wanted.items():
        got = tuple(state[name].shape)
        if got != tuple(tensor.shape):
            raise InputError(f"overlap_transformer: {path}: '{name}' has shape {got}, expected {tuple(tensor.shape)}")
    unknown = [n for n in state if n not in wanted and not n.startswith(_UNUSED_PREFIXES)]
    if unknown:
        raise InputError(f"overlap_transformer: {path} has unexpected weights: {', '.join(unknown[:5])}")
    net.load_state_dict({name: state[name] for name in wanted})
    return net.eval()


def convert_checkpoint(source: str | Path, target: str | Path) -> Path:
    """Write the inference weights of checkpoint `source` (as published, or a state_dict) as a plain
    state_dict at `target`, checked by loading it into the network first; refuses to overwrite a file."""
    torch = _import_torch()
    target = Path(target)
    if target.exists():
        raise InputError(f"overlap_transformer: {target} exists; give a new file name")
    torch.save(load_network(source).state_dict(), target)
    return target


class OverlapTransformer:
    """Learned yaw-invariant 256-d descriptor; `weights` is the path to the authors' checkpoint (module doc)."""

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
        image = range_projection(scan_points(points, "overlap_transformer"), max_range=self.max_range)
        return self.descriptors_from_range_images(image[None])[0]

    def similarity_many(self, query: np.ndarray, bank: np.ndarray) -> np.ndarray:
        """1 / (1 + ||query - d||) for each stored descriptor d."""
        bank = validate_bank(bank, self.shape, "overlap_transformer bank")
        q = validate_bank(np.asarray(query)[None], self.shape, "overlap_transformer query")[0]
        return 1.0 / (1.0 + np.linalg.norm(bank - q, axis=1))

    def similarity(self, a: np.ndarray, b: np.ndarray) -> float:
        """1 / (1 + ||a - b||)."""
        return float(self.similarity_many(a, np.asarray(b)[None])[0])
