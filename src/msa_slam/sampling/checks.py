"""Type and range checks of sampler parameters: one InputError naming the key, the value and what is allowed.

Values arrive from Python, YAML configs or `-p key=value` (parsed as YAML scalars), so a typo such as
`use_rho=maybe` or `alpha=.nan` must be refused here rather than coerced into a plausible run.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from msa_slam.errors import InputError


def _refuse(sampler: str, key: str, value: object, allowed: str) -> InputError:
    return InputError(f"sampler {sampler!r}: {key}={value!r} is not allowed; expected {allowed}")


def finite_float(sampler: str, key: str, value: object, minimum: float = -math.inf, *,
                 exclusive: bool = False, below: float | None = None) -> float:
    """A finite real number >= minimum (> minimum when exclusive; < below when given)."""
    bound = f"{'>' if exclusive else '>='} {minimum:g}" if minimum > -math.inf else ""
    if below is not None:
        bound = f"{bound} and < {below:g}" if bound else f"< {below:g}"
    allowed = f"a finite number {bound}".rstrip()
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise _refuse(sampler, key, value, allowed)
    number = float(value)
    if number < minimum or (exclusive and number == minimum) or (below is not None and number >= below):
        raise _refuse(sampler, key, value, allowed)
    return number


def integer(sampler: str, key: str, value: object, minimum: int, maximum: int | None = None) -> int:
    """An integer in [minimum, maximum] (an integral float such as 10.0 counts)."""
    allowed = f"an integer >= {minimum}" + (f" and <= {maximum}" if maximum is not None else "")
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) \
            or int(value) != value:
        raise _refuse(sampler, key, value, allowed)
    number = int(value)
    if number < minimum or (maximum is not None and number > maximum):
        raise _refuse(sampler, key, value, allowed)
    return number


def boolean(sampler: str, key: str, value: object) -> bool:
    """true or false (YAML's booleans), nothing else."""
    if not isinstance(value, (bool, np.bool_)):
        raise _refuse(sampler, key, value, "true or false")
    return bool(value)


def choice(sampler: str, key: str, value: object, options: tuple[str, ...]) -> str:
    """One of the named options."""
    if not isinstance(value, str) or value not in options:
        raise _refuse(sampler, key, value, f"one of {', '.join(options)}")
    return value
