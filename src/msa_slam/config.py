"""Configuration models: one pydantic model per stage, consumed by the stage directly (`Verifier(config)`,
`PoseGraph(config)`), composed into a run's configuration. Unknown keys and bad values become one
InputError line naming the key and, for an unknown key, the valid ones: a typo never runs the default."""

from __future__ import annotations

import typing
from collections.abc import Mapping
from contextvars import ContextVar
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, ValidationError

from msa_slam.errors import InputError

_nested: ContextVar[bool] = ContextVar("msa_slam_config_nested", default=False)


def _inner_model(annotation: Any) -> type[BaseModel] | None:
    """The model a field holds: itself, or the item model of a list or dict of models."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        inner = _inner_model(arg)
        if inner is not None:
            return inner
    return None


def section_model(model: type[BaseModel], path: tuple) -> type[BaseModel]:
    """The (nested) model at `path` of an error location (list indices and dict keys skipped)."""
    for part in path:
        field = model.model_fields.get(part) if isinstance(part, str) else None
        inner = None if field is None else _inner_model(field.annotation)
        if inner is not None:
            model = inner
    return model


def problem(error: Mapping[str, Any], model: type[BaseModel], root: str = "config") -> str:
    """One pydantic error as text: where it is and what is wrong (for an unknown key: the valid keys)."""
    explained = getattr(model, "explain_error", lambda e: None)(error)  # a model's own wording of its errors
    if explained is not None:
        return explained
    loc = tuple(error["loc"])
    where = ".".join(map(str, loc)) or root
    if error["type"] == "extra_forbidden":
        keys = section_model(model, loc[:-1]).model_fields
        return f"unknown key {where!r}; valid keys: {', '.join(keys)}"
    return f"{where}: {error['msg']}"


def validation_message(exc: ValidationError, model: type[BaseModel], root: str = "config") -> str:
    """All problems of a failed validation on one line."""
    return "; ".join(problem(e, model, root) for e in exc.errors())


def check_key_names(model: type[BaseModel], data: Mapping[Any, Any], where: str, section: str = "") -> None:
    """Every key of `data` and of its sections' mappings must be a name: pydantic hands a section's mapping to
    its model as keyword arguments, where a number (YAML `verifier: {1: 2}`) raises TypeError, not a
    validation error. `where` starts the InputError, `section` is the dotted path of `data` within it."""
    for key, value in data.items():
        if not isinstance(key, str):
            raise InputError(
                f"{where}: {section + ': ' if section else ''}key {key!r} is not a name; valid keys: "
                f"{', '.join(model.model_fields)}"
            )
        field = model.model_fields.get(key)
        if field is None or not isinstance(value, Mapping):
            continue
        path = f"{section}.{key}" if section else key
        inner = None if field.discriminator else _inner_model(field.annotation)
        if inner is not None:
            check_key_names(inner, value, where, path)
            continue
        odd = next((k for k in value if not isinstance(k, str)), None)
        # a stage's parameters (odometry_params), or a tagged union's (sampler_params: its model is chosen later)
        if odd is not None and (typing.get_origin(field.annotation) is dict or field.discriminator):
            raise InputError(f"{where}: {path}: key {odd!r} is not a parameter name")


def check_partial(model: type[BaseModel], data: Mapping[str, Any], where: str) -> None:
    """Check `data` as constructing `model` would, except that keys the model requires may be missing.

    A config file that command-line options complete (`run --config FILE -d DATASET`) is checked on its own
    this way, so an unknown or wrongly typed key is reported with `where` (the file) rather than only once
    the options are mixed in, when the message could no longer say where the key came from.
    """
    check_key_names(model, data, where)
    token = _nested.set(True)  # pydantic's own errors, so that the missing keys can be left out
    try:
        model.model_validate(dict(data))
    except ValidationError as exc:
        errors = [e for e in exc.errors() if not (e["type"] == "missing" and len(e["loc"]) == 1)]
        if errors:
            raise InputError(f"{where}: {'; '.join(problem(e, model) for e in errors)}") from None
    finally:
        _nested.reset(token)


class StageConfig(BaseModel):
    """Base of every stage's configuration: unknown keys, NaN and infinity are errors; assignments are
    validated; a failed construction raises one InputError line starting with the model's SECTION."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)
    SECTION: ClassVar[str] = "config"

    def __init__(self, **data: Any) -> None:
        if _nested.get():  # a section validated inside its parent: the parent reports the problem
            super().__init__(**data)
            return
        check_key_names(type(self), data, self.SECTION)
        token = _nested.set(True)
        try:
            super().__init__(**data)
        except ValidationError as exc:
            raise InputError(f"{self.SECTION}: {validation_message(exc, type(self), self.SECTION)}") from None
        finally:
            _nested.reset(token)
