"""Dataset specs: the one parser of every dataset spelling the commands accept (spec.py) and what a spec's
scans are opened as (sequence.py)."""

from msa_slam._lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(["LIVE_PREFIX", "SEED", "SIM_PREFIX", "SourceSpec", "parse_spec", "seeded", "spec_kind"], "spec"),
    **dict.fromkeys(["check_selection", "open_sequence", "open_source", "resolve_dataset"], "sequence"),
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
