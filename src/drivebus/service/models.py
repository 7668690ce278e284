"""Request bodies of the HTTP API: validated before anything reaches the machine.

Strict: a number must be a JSON number (not a string), an unknown field is an error;
NaN and infinities are refused. A failed validation is a 422 ``ArgumentError`` problem.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = [
    "GroupMoveRequest",
    "JogRequest",
    "LeaseRequest",
    "MoveRequest",
    "ReadRequest",
    "RecordingRequest",
    "StopRequest",
    "WriteRequest",
]

Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
Word = Annotated[int, Field(ge=0, le=0xFFFF)]

MAX_JOG_TTL = 10.0
"""The longest watchdog a client may give a jog: it must keep feeding it."""


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)


class MoveRequest(_Body):
    """A move to ``target`` or by ``by`` (exactly one), in the axis's units; speed in
    units/s, accel and decel in units/s² (default: the axis's config); ``buffer``: what
    it does to a motion under way (PLCopen buffer mode, as ``Axis.move_to``)."""

    target: Finite | None = None
    by: Finite | None = None
    speed: Positive | None = None
    accel: Positive | None = None
    decel: Positive | None = None
    buffer: Literal["aborting", "buffered", "blending"] = Field(
        "aborting",
        description="aborting: take over the motion under way where the drive takes a new "
                    "target on the fly (else 409 StateError); buffered: start once the "
                    "motions under way are in position; blending: pass into it without "
                    "stopping where the drive can (else buffered, and the result says why)")

    @model_validator(mode="after")
    def _one_goal(self) -> MoveRequest:
        if (self.target is None) == (self.by is None):
            raise ValueError("give exactly one of 'target' and 'by'")
        return self

    model_config = ConfigDict(
        extra="forbid", strict=True,
        json_schema_extra={"examples": [{"target": 12.5}, {"by": -3, "speed": 20},
                                        {"target": 40, "buffer": "buffered"}]},
    )


class GroupMoveRequest(_Body):
    """A coordinated move: every named axis arrives at its target together."""

    targets: Annotated[dict[str, Finite], Field(min_length=1)]

    model_config = ConfigDict(
        extra="forbid", strict=True,
        json_schema_extra={"examples": [{"targets": {"x": 10, "y": 20}}]},
    )


class NoParameters(_Body):
    """A command that takes no parameters (home, enable, disable, reset): no body or
    ``{}``; a key in it is refused (``422``) rather than ignored."""


class StopRequest(_Body):
    """A decelerating stop, optionally with its own deceleration (units/s²)."""

    decel: Positive | None = None


class JogRequest(_Body):
    """Jog at ``speed`` units/s (sign: direction; 0 stops) until ``ttl`` seconds after the
    last such request: the client feeds the jog by repeating it."""

    speed: Finite
    ttl: Annotated[float, Field(gt=0, le=MAX_JOG_TTL, allow_inf_nan=False)] = 0.5
    accel: Positive | None = None
    decel: Positive | None = None


class LeaseRequest(_Body):
    """Take (or renew) the command lease for ``ttl`` seconds."""

    ttl: Annotated[float, Field(gt=0, le=3600, allow_inf_nan=False)] = 30.0


class RecordingRequest(_Body):
    """Record these axes (and their lines); none given: every axis."""

    axes: list[str] | None = None


class ReadRequest(_Body):
    """Read ``count`` holding (or ``input``) registers from slave ``address``."""

    address: Annotated[int, Field(ge=1, le=247)]
    first: Word = Field(alias="register", description="the first register's address")
    count: Annotated[int, Field(ge=1, le=125)] = 1
    input: bool = False

    model_config = ConfigDict(
        extra="forbid", strict=True,
        json_schema_extra={"examples": [{"address": 3, "register": 18, "count": 2}]},
    )


class WriteRequest(_Body):
    """Write ``values`` to consecutive registers of slave ``address`` (0: broadcast)."""

    address: Annotated[int, Field(ge=0, le=247)]
    first: Word = Field(alias="register", description="the first register's address")
    values: Annotated[list[Word], Field(min_length=1, max_length=123)]

    model_config = ConfigDict(
        extra="forbid", strict=True,
        json_schema_extra={"examples": [{"address": 3, "register": 18, "values": [1]}]},
    )


class ParametersRequest(_Body):
    """``PUT /api/axes/{name}/parameters``: values by parameter key (as
    ``GET .../parameters`` names them); only those that differ are written."""

    values: Annotated[dict[str, int], Field(min_length=1)]
    save: bool = Field(False, description="store them in the drive's EEPROM once at the end")
    dry_run: bool = Field(False, description="only say what would be written")
    include_comms: bool = Field(
        False, description="also write the drive's address and line settings parameters")
