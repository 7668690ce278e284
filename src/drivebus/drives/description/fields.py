"""The pieces every section of a description is made of: the base model (unknown keys
refused, frozen), the field types that parse expressions, templates, scales, units and
sources, and where an item comes from (``SOURCE_KINDS``).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

from drivebus.drives.expr import Expr, ExprError, Template
from drivebus.drives.units import check_unit, parse_scale

FORMAT_VERSION = 1


def _expr(v: Any) -> Any:
    if isinstance(v, Expr):
        return v
    try:
        return Expr.parse(v)
    except ExprError as exc:
        raise ValueError(str(exc)) from None


def _template(v: Any) -> Any:
    if isinstance(v, Template):
        return v
    if not isinstance(v, str):
        raise ValueError(f"expected a text, got {v!r}")
    try:
        return Template.parse(v)
    except ExprError as exc:
        raise ValueError(str(exc)) from None


def _int_keys(v: Any) -> Any:
    """TOML keys are texts: ``"1"`` and ``"0x10"`` become ints."""
    if not isinstance(v, Mapping):
        return v
    out = {}
    for k, val in v.items():
        if isinstance(k, str):
            try:
                k = int(k, 0)
            except ValueError:
                raise ValueError(f"key {k!r} is not a whole number (like 4 or 0x10)") from None
        out[k] = val
    return out


def _scale(v: Any) -> float:
    try:
        return parse_scale(v)
    except ValueError as exc:
        raise ValueError(str(exc)) from None


def _unit(v: Any) -> Any:
    return check_unit(v) if isinstance(v, str) else v


SOURCE_KINDS = ("manual", "code", "inferred")
"""Where an item of a description comes from: the manual (document, section or page),
public code that drives the drive, or inferred (the description's author's reading)."""


SECTION_SOURCE = ("where the section's facts come from ('manual: ...', 'code: ...', "
                  "'inferred: ...'); without it, [drive] source")
"""What ``source`` means in ``[identify]``, ``[link]``, ``[status]`` and ``[alarms]``."""


def _source(v: Any) -> Any:
    if not isinstance(v, str):
        return v
    kind = re.split(r"[\s:]", v.strip(), maxsplit=1)[0].lower()
    if kind not in SOURCE_KINDS or not v.strip()[len(kind):].strip(" :"):
        raise ValueError(f"source {v!r}: say where it comes from, starting with manual, "
                         f"code or inferred: 'manual: 920-0176 App. 5, p. 110', 'code: "
                         f"github.com/owner/repo driver.py', 'inferred: why'")
    return v.strip()


def source_kind(source: str | None) -> str:
    """``manual``, ``code`` or ``inferred`` of a ``source`` text; ``unnamed`` for None."""
    if not source:
        return "unnamed"
    return re.split(r"[\s:]", source, maxsplit=1)[0].lower()


E = Annotated[Expr, BeforeValidator(_expr)]
Source = Annotated[str, BeforeValidator(_source)]
Unit = Annotated[str, BeforeValidator(_unit)]
T = Annotated[Template, BeforeValidator(_template)]
Scale = Annotated[float, BeforeValidator(_scale)]
IntKeyed = BeforeValidator(_int_keys)
Word = Annotated[int, Field(ge=0, le=0xFFFF)]
_KEY = r"^[A-Za-z_][A-Za-z0-9_]*$"


class _Model(BaseModel):
    model_config = ConfigDict(
        extra="forbid", frozen=True, allow_inf_nan=False, arbitrary_types_allowed=True,
        strict=True,
        populate_by_name=True,
    )
