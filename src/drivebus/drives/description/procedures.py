"""``[procedures]``: what the engine runs for each command, as ordered steps (write,
read, modify, call, check, wait, set, fail, return), and the common procedures'
names and parameters (``PROCEDURES``).
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property
from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, ConfigDict, Field, model_validator

from drivebus.drives.description.fields import _KEY, E, Source, T, _Model
from drivebus.drives.expr import Expr, Template


class WriteItem(_Model):
    """A value to write, with constraints beyond the register's range."""

    value: E
    nonzero: bool = Field(False, description="the raw value must not be 0 (a move's speed)")
    raw: bool = Field(False, description="the value is what the register holds (no unit "
                      "conversion; still range-checked): a fastest ramp code, a bit pattern")


def _item(v: Any) -> Any:
    return v if isinstance(v, Mapping | WriteItem) else {"value": v}


Priorities = Literal["emergency", "command", "config", "poll"]
_ACTIONS = ("write", "read", "modify", "call", "check", "wait", "set", "fail", "return_")


class Step(_Model):
    """One step of a procedure (exactly one action key, plus modifiers)."""

    model_config = ConfigDict(populate_by_name=True)

    write: dict[str, Annotated[WriteItem, BeforeValidator(_item)]] | None = None
    read: list[str | list[str]] | None = None
    modify: str | None = None
    call: str | None = None
    check: E | None = None
    wait: E | None = None
    set: dict[str, E] | None = None
    fail: T | None = None
    return_: E | None = Field(None, alias="return")
    # modifiers
    when: E | None = None
    block: E | None = None
    single: bool = Field(False, description="32-bit values as FC06 word by word")
    idempotent: bool = True
    priority: Priorities | None = None
    start: bool = Field(False, description="where a prepared move starts")
    volatile: bool = False
    end: bool = Field(False, description="the procedure ends after this step")
    args: dict[str, E] = {}
    bits_set: E | None = Field(None, alias="set_bits")
    bits_clear: E | None = Field(None, alias="clear_bits")
    bits_toggle: E | None = Field(None, alias="toggle_bits")
    pulse: bool = Field(False, description="modify: toggle, then toggle back")
    if_changed: bool = Field(False, description="write: only the registers whose value "
                             "differs from what the drive holds (read in this run, else "
                             "read now)")
    each: str | None = Field(None, pattern=r"^\s*[A-Za-z_][A-Za-z0-9_]*\s+in\s+.+$",
                             description="write: 'NAME in EXPRESSION', the step's writes "
                             "once per value of a list (per key of a map, in its order; "
                             "in one block with `block`)")
    timeout: E = Expr.parse(5.0)
    every: float = Field(0.005, gt=0, le=10)
    error: Literal["alarm", "state", "motion", "limit"] = "state"
    message: T | None = None

    @model_validator(mode="after")
    def _one_action(self) -> Step:
        given = [a.rstrip("_") for a in _ACTIONS if getattr(self, a) is not None]
        if self.wait is not None and "read" in given:
            given.remove("read")  # a wait's `read`: what each of its polls reads
        if len(given) != 1:
            keys = ", ".join(a.rstrip("_") for a in _ACTIONS)
            got = f"got {', '.join(given)}" if given else "got none"
            raise ValueError(f"a step has exactly one of {keys} ({got})")
        if self.modify is not None and self.bits_set is None and self.bits_clear is None \
                and self.bits_toggle is None:
            raise ValueError("a modify step needs set_bits, clear_bits or toggle_bits")
        if self.each is not None:
            if self.write is None:
                raise ValueError("'each' repeats a write step only")
            Expr.parse(self.each.split(" in ", 1)[1])
        return self

    @cached_property
    def action(self) -> str:
        """The step's action key (asked at every step of every run: found once)."""
        if self.wait is not None:
            return "wait"
        return next(a.rstrip("_") for a in _ACTIONS if getattr(self, a) is not None)


class Param(_Model):
    """A parameter of a procedure of the drive's own."""

    name: str = Field(pattern=_KEY)
    default: Any = None
    doc: str = ""


def _param(v: Any) -> Any:
    return {"name": v} if isinstance(v, str) else v


class Procedure(_Model):
    """One procedure: its steps, or why the drive cannot do it."""

    steps: list[Step] = []
    params: list[Annotated[Param, BeforeValidator(_param)]] = []
    what: T | None = None
    unsupported: str | None = None
    supported: E | None = Field(None, description="a condition on the options")
    why: str = ""
    priority: Priorities | None = None
    takes: list[str] | None = Field(None, description="the parameters it honours (default: "
                                    "those its steps use); a stop that takes no decel refuses "
                                    "one before anything is sent")
    doc: str = ""
    source: Source | None = None

    def uses(self) -> set[str]:
        """The names its steps' expressions use (what it honours of its parameters)."""
        names: set[str] = set()
        for step in self.steps:
            for value in step.__dict__.values():
                if isinstance(value, Expr | Template):
                    names |= value.names
            for item in (step.write or {}).values():
                names |= item.value.names
            for e in (*(step.set or {}).values(), *step.args.values()):
                names |= e.names
            if step.each is not None:
                names |= Expr.parse(step.each.split(" in ", 1)[1]).names
        return names

    def honours(self, param: str) -> bool:
        """Whether it takes parameter ``param`` (``takes``, else its steps use it)."""
        return param in self.takes if self.takes is not None else param in self.uses()

    @model_validator(mode="after")
    def _check(self) -> Procedure:
        if self.unsupported is not None and self.steps:
            raise ValueError("an unsupported procedure has no steps")
        if self.unsupported is None and not self.steps:
            raise ValueError("needs steps (or 'unsupported' with the reason)")
        return self


PROCEDURES: dict[str, tuple[str, tuple[str, ...]]] = {
    "learn": ("learn what decoding needs (reads only)", ()),
    "setup": ("set the drive up", ()),
    "enable": ("enable the motor", ()),
    "disable": ("disable the motor", ()),
    "move_absolute": ("make an absolute move", ("target", "speed", "accel", "decel")),
    "move_relative": ("make a relative move", ("distance", "speed", "accel", "decel")),
    "speed_run": ("run at a set speed", ("speed", "accel", "decel")),
    "stop": ("stop with deceleration", ("decel",)),
    "emergency_stop": ("make an emergency stop", ()),
    "home": ("home", ("method", "speed", "creep", "accel", "offset")),
    "clear_alarm": ("clear an alarm", ()),
    "zero_position": ("set its position to zero", ()),
    "save_parameters": ("save parameters", ()),
    "retarget_absolute": ("take a new target while it moves",
                          ("target", "speed", "accel", "decel")),
}
"""The common procedures: what a NotSupported error says, and the names they pass."""

EXTRA_PROCEDURES = ("set_output", "prepare_table", "start_table")
"""Procedures the engine runs besides the common ones (I/O and motion programs)."""
