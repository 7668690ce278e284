"""``[twin]``: how the drive behaves, for its simulated twin (``drivebus.sim.described``):
what it does when a register is written or an input function changes
(``TWIN_ACTIONS``), at a limit switch and in a homing.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from drivebus.drives.description.fields import E, _Model
from drivebus.drives.expr import Expr

TWIN_ACTIONS = {
    "move_absolute": ("target", "speed", "accel", "decel"),
    "move_relative": ("distance", "speed", "accel", "decel"),
    "run": ("speed", "accel", "decel"),
    "set_speed": ("speed",),
    "stop": ("decel",),
    "emergency_stop": ("decel",),
    "home": ("method", "speed", "creep", "accel", "offset"),
    "enable": (),
    "disable": (),
    "clear_alarm": (),
    "zero_position": (),
    "set_position": ("position",),
    "save": (),
    "factory_reset": (),
    "run_table": ("rows", "target", "distance", "speed", "accel", "decel", "wait", "repeat"),
    "refuse": (),
    "none": (),
}
"""What a twin does on a trigger, and the parameters each action takes."""


class Trigger(_Model):
    """What the drive does when a register is written."""

    reg: str = Field(alias="register")
    when: E | None = None
    do: Literal[tuple(TWIN_ACTIONS)]  # type: ignore[valid-type]
    target: E | None = None
    distance: E | None = None
    speed: E | None = None
    accel: E | None = None
    decel: E | None = None
    creep: E | None = None
    method: E | None = None
    offset: E | None = None
    position: E | None = None
    rows: E | None = Field(None, description="run_table: how many rows run (`row` counts "
                           "from 1 in the row expressions)")
    wait: E | None = Field(None, description="run_table: s to wait after a row's move")
    repeat: E | None = Field(None, description="run_table: run the rows again and again "
                             "(the last row's wait kept) until stopped")
    motion: str | None = Field(None, description="the motion kind it starts (mode register)")
    more: bool = Field(False, description="go on to the next triggers of the register")
    refuse: bool = Field(False, description="refuse with refusals.busy when it cannot start")
    set: dict[str, E] = Field({}, description="registers the drive sets when the trigger "
                              "fires, raw values (an acknowledge, a command register it "
                              "clears)")
    ends: dict[str, E] = Field({}, description="registers the drive sets once the motion "
                               "the trigger started is over (done, failed or stopped), raw "
                               "values (a command register that reads back while it runs)")


class InputTrigger(Trigger):
    """What the drive does when an input function turns active (or inactive)."""

    reg: str = Field("", alias="register")
    input: str = Field(description="the input function ([inputs] codes)")
    edge: Literal["rise", "fall"] = "rise"


class LimitsDef(_Model):
    """How the drive reacts at a limit switch."""

    stop: E = Expr.parse("'decelerate'")
    decel: E | None = None
    block_start: bool = True


class TwinHomingDef(_Model):
    """``[twin.homing]``: how a ``reference_edge`` homing leaves its reference and what a
    limit switch in the search does."""

    backoff: Literal["speed", "creep"] = Field(
        "speed", description="the speed of the leg that backs off the reference")
    backoff_stop: Literal["brake", "at_once"] = Field(
        "brake", description="where the back-off leaves the reference: brake at the homing "
        "acceleration, or stop at once on the edge")
    reverse_at_limit: E = Field(Expr.parse(True), description="a limit switch met ahead in "
                                "the search reverses it (else the homing fails there)")
    after_reversal: Literal["other_edge", "same_edge"] = Field(
        "other_edge", description="after a reversal: search the reference's other edge, or "
        "pass through the reference and creep back to the edge the search looked for")
    offset: E | None = Field(None, description="what the offset does, chosen when the homing "
                             "starts: an expression giving 'origin', 'move' or 'travel' "
                             "(default: [twin] home_offset)")
    offset_speed: Literal["creep", "speed"] = Field(
        "creep", description="the speed of an offset travelled after the origin")


class TwinDef(_Model):
    """``[twin]``: how the drive behaves, for its simulated twin."""

    on_write: list[Trigger] = []
    on_input: list[InputTrigger] = Field(
        [], description="actions on an input function's edge (a terminal, its polarity bit "
        "or its function changed)")
    direct: list[Literal["home_switch", "limit_positive", "limit_negative"]] = Field(
        [], description="switches the drive sees without an input terminal")
    options: list[str] = Field([], description="registers a twin option sets before "
                               "power-up (a choice the machine's builder made: wiring, mode)")
    stall_time: E = Field(Expr.parse(0.0), description="s: how long the motor stalls on a "
                          "hard stop before the drive takes it as the origin (hard_stop)")
    starts: E = Expr.parse("enabled and not alarm")
    limits: LimitsDef = LimitsDef()
    eeprom_write_through: E | None = Field(
        None, description="when a write to an `eeprom` register is stored (default: the "
        "[eeprom] write-through switch holds its `on` value)")
    enabled: E = Expr.parse(True)
    decel: E | None = Field(None, description="an alarm or a disable: None = at once")
    wiring: dict[Literal["home_switch", "limit_positive", "limit_negative"], str | int] = Field(
        {}, description="the input terminal (a name of [inputs] names, or a bit) each "
        "simulated switch is wired to; the drive acts on it as its function register and "
        "[inputs] polarity say")
    max_pulse_rate: float | None = Field(None, gt=0, description="pulses/s: the fastest "
                                         "the drive's pulse output runs (speeds above are capped)")
    home_offset: Literal["origin", "move", "travel"] = Field(
        "origin", description="origin: the origin edge takes the offset as its position; "
        "move: the counter is 0 at the edge and a compensation move of the offset follows; "
        "travel: the offset is travelled past the edge and the point reached is 0")
    homing: TwinHomingDef = TwinHomingDef()
