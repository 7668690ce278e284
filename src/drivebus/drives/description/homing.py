"""``[homing]``: the drive's homing methods, each its code for the drive and the
behaviour its twin plays.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from drivebus.drives.cia402 import HOMING_METHODS
from drivebus.drives.description.fields import Source, _Model


class HomingMethod(BaseModel):
    """One homing method: its code for the drive and the behaviour its twin plays."""

    model_config = ConfigDict(extra="allow", frozen=True)

    code: int | None = None
    cia402: int | None = Field(None, description="the equivalent CiA 402 method (twin)")
    behaviour: Literal["search", "set", "move_to_offset", "reference_edge", "hard_stop"] | \
        None = None
    reference: Literal["home_switch", "limit_positive", "limit_negative"] | None = Field(
        None, description="reference_edge: the signal whose rising edge is the origin")
    direction: Literal[-1, 1] | None = Field(None, description="reference_edge, hard_stop: "
                                             "the search direction")
    doc: str = ""
    source: Source | None = None

    @model_validator(mode="after")
    def _reference(self) -> HomingMethod:
        if self.cia402 is not None and self.cia402 not in HOMING_METHODS:
            raise ValueError(f"cia402: {self.cia402} is no CiA 402 homing method (6098h: "
                             f"1-14, 17-30, 33-35 and 37; -128..-1 are the manufacturer's, "
                             f"which a twin cannot play)")
        if self.behaviour == "reference_edge" and (self.reference is None or
                                                   self.direction is None):
            raise ValueError("behaviour reference_edge needs 'reference' and 'direction'")
        if self.behaviour == "hard_stop" and self.direction is None:
            raise ValueError("behaviour hard_stop needs 'direction'")
        return self

    @property
    def extras(self) -> dict[str, Any]:
        """The method's further values (usable as ``home.NAME`` in expressions)."""
        return dict(self.model_extra or {})


class HomingDef(_Model):
    """``[homing]``: the drive's homing methods, the first is the default."""

    methods: dict[str, HomingMethod] = Field(min_length=1)
