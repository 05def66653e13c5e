"""Batch and online SLAM pipelines (the paper's Table I and Table II protocols) over the shared core
(msa_slam.slam)."""

from msa_slam._lazy import lazy_exports

_EXPORTS = {
    "run_batch": "batch",
    **dict.fromkeys(["RunConfig", "apply_params", "load_config", "make_config"], "config"),
    **dict.fromkeys(["Frontend", "prepare_frontend"], "frontend"),
    "run_online": "online",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
