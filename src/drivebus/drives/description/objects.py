"""``[cia402]``: how a CiA 402 drive maps its objects to registers, and the object a
register's ``object`` names (``object_name``).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from drivebus.drives.description.fields import E, Scale, Unit, _Model


class ObjectUnit(_Model):
    """How the registers of one kind of CiA 402 object hold their values."""

    unit: Unit
    scale: Scale = 1.0


class Cia402Def(_Model):
    """``[cia402]``: how a CiA 402 drive maps its objects and runs its state machine."""

    address_rule: E | None = Field(None, description="the address of an object from its "
                                   "`index` and `sub` (for the objects listed in `objects`)")
    objects: list[str] = Field([], description="objects whose registers the rule places")
    words: Literal[2] | None = Field(None, description="2: every object the rule places "
                                     "takes two registers, 16-bit ones too (a drive that "
                                     "stores each parameter in 32 bits); default: by the "
                                     "object's width")
    position: ObjectUnit = ObjectUnit(unit="pulses")
    velocity: ObjectUnit = ObjectUnit(unit="pulses/s")
    acceleration: ObjectUnit = ObjectUnit(unit="pulses/s²")
    emergency_stop: Literal["quick_stop", "halt"] = "quick_stop"
    change_set_immediately: bool = Field(False, description="a new move replaces a running "
                                         "one at once (controlword bit 5)")
    timeout: float = Field(1.0, gt=0, le=30, description="s, for a state change or a "
                           "set-point acknowledge")
    blocks: list[Annotated[list[str], Field(min_length=2)]] = Field(
        [], description="objects the drive takes in one FC16, each list at registers that "
        "follow on ('profile_velocity', 'profile_acceleration'); every other object is "
        "written in a request of its own")

    def block_of(self, name: str) -> int | None:
        """The index of the block of ``blocks`` object ``name`` belongs to (None: none)."""
        for i, block in enumerate(self.blocks):
            if any(object_name(ref) == name for ref in block):
                return i
        return None


def object_name(ref: str) -> str | None:
    """The CiA 402 object ``ref`` names: an object name, or its index (``6040``,
    ``0x6040``, ``6040h``) with an optional sub-index (``6099:01``, ``6099.1``)."""
    from drivebus.drives.cia402 import OBJECTS

    if ref in OBJECTS:
        return ref
    text = ref.strip().lower().removeprefix("0x")
    index_s, _, sub_s = text.replace(".", ":").partition(":")
    index_s = index_s.removesuffix("h")
    try:
        index = int(index_s, 16)
        sub = int(sub_s.removesuffix("h"), 16) if sub_s else 0
    except ValueError:
        return None
    for name, info in OBJECTS.items():
        if info.index == index and info.subindex == sub:
            return name
    return None


def _object_kind(name: str) -> str | None:
    """Which of ``[cia402]``'s units an object's registers take."""
    if name in ("position_actual_value", "target_position", "home_offset"):
        return "position"
    if name in ("velocity_actual_value", "profile_velocity", "target_velocity",
                "homing_speed_search", "homing_speed_zero"):
        return "velocity"
    if name in ("profile_acceleration", "profile_deceleration", "quick_stop_deceleration",
                "homing_acceleration"):
        return "acceleration"
    return None
