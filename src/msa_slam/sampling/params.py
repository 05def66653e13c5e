"""Typed sampler parameters: each sampler's pydantic model (its fields, ranges and cross-field rules), checked
once where a configuration is built, and the one wording of their errors.

Values arrive from Python, YAML configs or `-p key=value` (parsed as YAML scalars), so a typo such as
`use_rho=maybe`, `alpha=.nan` or `window="8"` is refused rather than coerced into a plausible run: numbers must
be numbers (not booleans, not strings), integers may be written 10.0, booleans must be YAML's true or false.

A model is also a read-only mapping of the parameters it was GIVEN, with the values as given: that is what a
run's configuration echoes (config.yaml, metrics.json, labels), so defaults never appear in a config dump.
"""

from __future__ import annotations

import numbers
from collections.abc import Iterator, Mapping
from typing import Annotated, Any, ClassVar

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, PrivateAttr, ValidationError, model_validator
from pydantic_core import PydanticCustomError

from msa_slam.errors import InputError

GATE_PARAMETERS = ("min_motion", "min_rotation")  # the standstill gate's, taken by every sampler
MAX_MIN_ROTATION = 180.0  # degrees: no rotation is larger, so a larger min_rotation would mean nothing else
TAG = "sampler"  # the field naming a model's sampler: the discriminator of a run's tagged union


def _real(value: Any) -> Any:
    """Numbers only: pydantic would read True as 1 and "3" as 3."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise PydanticCustomError("not_a_number", "not a number")
    return value


def _boolean(value: Any) -> Any:
    """YAML's true or false only (numpy's too): pydantic would read 1 and "yes" as true."""
    if not isinstance(value, (bool, np.bool_)):
        raise PydanticCustomError("not_a_boolean", "not true or false")
    return bool(value)


Real = Annotated[float, BeforeValidator(_real)]
Integer = Annotated[int, BeforeValidator(_real)]
Boolean = Annotated[bool, BeforeValidator(_boolean)]


def rule(message: str) -> PydanticCustomError:
    """A cross-field rule's error (the message is shown after the sampler's name)."""
    return PydanticCustomError("sampler_rule", message)


class SamplerParams(BaseModel, Mapping):
    """Parameters every sampler takes: the standstill gate (sampling/base.py; off by default).

    Subclasses add their sampler's fields and a `sampler` tag (Literal of its name)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)
    NAME: ClassVar[str] = "sampler"

    min_motion: Real = Field(
        0.0,
        ge=0,
        description="metres a frame must move from the last frame the gate passed on to be passed on (0: no gate)",
    )
    min_rotation: Real = Field(
        0.0, ge=0, lt=MAX_MIN_ROTATION, description="degrees of turn that pass a frame that moved less than min_motion"
    )
    _given: dict[str, Any] = PrivateAttr(default_factory=dict)

    @model_validator(mode="wrap")
    @classmethod
    def _keep_given(cls, data: Any, handler: Any) -> SamplerParams:
        """Remember the parameters as given: the run's configuration echoes them, not the defaults."""
        model = handler(data)
        if isinstance(data, Mapping) and model is not data:
            model._given = {k: v for k, v in data.items() if k != TAG}
        return model

    @model_validator(mode="after")
    def _gate(self) -> SamplerParams:
        if self.min_rotation > 0 and self.min_motion == 0:
            raise rule(
                f"min_rotation={self.min_rotation!r} needs min_motion > 0 "
                "(the standstill gate holds back frames that moved less than min_motion metres, unless they "
                "turned at least min_rotation degrees); set min_motion, or min_rotation=0"
            )
        return self

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """Parameter names and defaults, the sampler's own first, then the gate's."""
        names = [n for n in cls.model_fields if n not in (TAG, *GATE_PARAMETERS)] + list(GATE_PARAMETERS)
        return {n: cls.model_fields[n].default for n in names}

    def __getitem__(self, key: str) -> Any:
        return self._given[key]

    def __iter__(self) -> Iterator[str]:  # type: ignore[override]  # a mapping's keys, not pydantic's pairs
        return iter(self._given)

    def __len__(self) -> int:
        return len(self._given)

    def __eq__(self, other: object) -> bool:
        """Equal as mappings (the parameters given), as a dict equals any mapping of the same items."""
        return isinstance(other, Mapping) and self._given == dict(other)

    __hash__ = None  # type: ignore[assignment]  # a mapping


def expected(model: type[BaseModel], key: str) -> str:
    """What field `key` of `model` allows, in words ("an integer >= 3", "a finite number > 0 and < 1")."""
    field = model.model_fields[key]
    choices = getattr(field.annotation, "__args__", None)
    if choices and all(isinstance(c, str) for c in choices):
        return f"one of {', '.join(choices)}"
    if field.annotation is bool:
        return "true or false"
    bounds = [
        f"{sign} {getattr(m, attr):g}"
        for m in field.metadata  # pydantic's Ge(ge=3), Lt(lt=1), ...
        for attr, sign in (("ge", ">="), ("gt", ">"), ("lt", "<"), ("le", "<="))
        if hasattr(m, attr)
    ]
    what = "an integer" if field.annotation is int else "a finite number"
    return " ".join([what, " and ".join(bounds)]).strip()


def explain(model: type[SamplerParams], error: Mapping[str, Any]) -> str:
    """One pydantic error of `model` as "sampler 'NAME': key=value is not allowed; expected ...", or the
    unknown key with every parameter and its default."""
    where = f"sampler {model.NAME!r}"
    loc = tuple(error["loc"])
    if error["type"] == "extra_forbidden":
        listing = ", ".join(f"{k}={v!r}" for k, v in model.defaults().items())
        return f"{where}: unknown parameter(s) {loc[-1]}; it takes: {listing}"
    if error["type"] == "sampler_rule" or not loc:
        return f"{where}: {error['msg']}"
    key = str(loc[0])
    value = error["input"]
    return f"{where}: {key}={value!r} is not allowed; expected {expected(model, key)}"


def check_params(model: type[SamplerParams], given: Mapping[str, Any]) -> SamplerParams:
    """`given` validated as `model`: one InputError naming the sampler, each bad key and what it allows."""
    try:
        return model.model_validate(dict(given))
    except ValidationError as exc:
        raise InputError("; ".join(explain(model, e) for e in exc.errors())) from None
