"""One run of one sampler, batch or online (the paper's Table I and Table II protocols), over the shared core
(msa_slam.slam): `run(config, source)` over a cached batch front end or a live one, and the run's config."""

from msa_slam._lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(["FrontEnd", "run"], "driver"),
    **dict.fromkeys(
        ["OnlineConfig", "RunConfig", "apply_params", "load_config", "make_config", "make_online_config"], "config"
    ),
    **dict.fromkeys(["CachedFrontEnd", "prepare_frontend"], "frontend"),
    "LiveFrontEnd": "live",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
