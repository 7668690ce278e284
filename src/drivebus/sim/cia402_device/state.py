"""What the simulated CiA 402 device is built from (``Cia402Setup``, ``FACTORY_VALUES``)
and the records of what it is doing: a set-point, a homing and the edges it watches,
the next events.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Literal

from drivebus.drives.cia402 import HOMING_METHODS, HomingMethod, Mode

FACTORY_VALUES: Mapping[str, int] = {
    "controlword": 0,
    "quick_stop_option_code": 2,
    "halt_option_code": 1,
    "modes_of_operation": 0,
    "target_position": 0,
    "home_offset": 0,
    "profile_velocity": 10_000,
    "profile_acceleration": 100_000,
    "profile_deceleration": 100_000,
    "quick_stop_deceleration": 1_000_000,
    "homing_method": 0,
    "homing_speed_search": 10_000,
    "homing_speed_zero": 1_000,
    "homing_acceleration": 100_000,
    "target_velocity": 0,
}
"""The writable objects' values at power-up (in the objects' units), unless the device is
given others."""


_QUICK_STOP_OPTIONS = range(0, 9)


_AT_ONCE = 1e12
"""Increments/s² of a ramp that an acceleration object of 0 asks for (no ramp)."""


_HALT_OPTIONS = range(1, 5)


_SUPPORTED = frozenset({Mode.PROFILE_POSITION, Mode.PROFILE_VELOCITY, Mode.HOMING})


@dataclass(frozen=True, kw_only=True)
class Cia402Setup:
    """How a simulated CiA 402 drive and its axis are built: units, switches, encoder."""

    position: int = 0
    """The position counter (increments) at power-up; the switches' frame."""
    home_switch: float | None = None
    """Where the home switch's edge is (its lower edge for a switch of ``home_switch_width``)."""
    home_cam: Literal["positive", "negative"] | None = None
    """Without a width: the home switch is active on this side of ``home_switch`` (None:
    on the side the homing method in 6098h expects, so that it homes from either side)."""
    home_switch_width: float | None = None
    """The home switch covers [home_switch, home_switch + width] (homing methods 7-14, 23-30)."""
    limit_negative: float | None = None
    """The negative limit switch is active at and below this position."""
    limit_positive: float | None = None
    """The positive limit switch is active at and above this position."""
    increments_per_rev: int = 10_000
    """Encoder increments per motor revolution: one index pulse each."""
    index_offset: float = 0.0
    """A position where an index pulse is (the others are a revolution apart)."""
    velocity_unit: float = 1.0
    """Increments/s of one unit of the velocity objects (e.g. increments_per_rev / 60 for rpm)."""
    acceleration_unit: float = 1.0
    """Increments/s² of one unit of the acceleration objects."""
    modes: frozenset[Mode] = _SUPPORTED
    """The modes of operation the drive accepts (a subset of PP, PV, homing)."""
    homing_methods: frozenset[int] = frozenset(HOMING_METHODS)
    """The homing methods the drive accepts (0 is always accepted: no method)."""
    switch_on_enables: bool = False
    """Enable operation in Ready to switch on goes on to Operation enabled (3 then 4)."""
    boot_time: float = 0.0
    """Seconds in Not ready to switch on after power-up."""
    absolute_encoder: bool = False
    """The position survives a power cycle (else the counter restarts at 0)."""

    def __post_init__(self) -> None:
        if not self.modes <= _SUPPORTED:
            raise ValueError(f"the simulated CiA 402 device runs only {sorted(_SUPPORTED)}")
        if self.increments_per_rev <= 0 or self.velocity_unit <= 0 or self.acceleration_unit <= 0:
            raise ValueError("increments per revolution and units must be > 0")


@dataclass(frozen=True)
class _Edge:
    """A switch edge the homing may cross: its physical position and the side (+1/-1) on
    which the switch is active."""

    position: float
    active_side: int
    name: str


_BAND = 2e-6
"""Increments past an edge at which the homing takes it as passed: a tiny hysteresis, so
that an axis that turns round on an edge (or starts on one) is seen to pass it each time."""


@dataclass
class _Watch:
    """An edge the homing watches, and the side of it (+1/-1) the axis is on."""

    kind: Literal["home", "index", "limit"]
    edge: _Edge
    side: int


@dataclass
class _Homing:
    """A homing in progress."""

    method: HomingMethod
    direction: int
    watches: list[_Watch]
    final: bool = False
    reversed: bool = False
    t_from: float = 0.0  # events are looked for from here on


@dataclass
class _PointSet:
    """A profile position set-point as the drive took it."""

    target: float
    velocity: float
    acceleration: float
    deceleration: float


@dataclass
class _Profile:
    """Profile position bookkeeping."""

    target: float | None = None  # the set-point in progress or last reached (counter frame)
    pending: _PointSet | None = None  # waits behind the one in progress
    acknowledge: bool = False
    ended_short: bool = False  # halt, limit switch, quick stop: relative moves start here
    stalled: bool = False  # taken but cannot move (no speed or ramp)
    halted: float | None = None  # the target a halt interrupted: continued when halt clears


_Action = Callable[[float], None]


@dataclass
class _Events:
    """Candidates for the next internal event: (time, action at that time); earliest wins."""

    items: list[tuple[float, _Action]] = field(default_factory=list)

    def add(self, t: float | None, action: _Action) -> None:
        """A candidate at ``t`` (None: none)."""
        if t is not None:
            self.items.append((t, action))

    def first(self) -> tuple[float, _Action] | None:
        """The earliest candidate (the first added among equals)."""
        return min(self.items, key=lambda item: item[0]) if self.items else None
