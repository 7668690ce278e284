"""What a described twin keeps about the work under way: where an address sits in the
map, the legs of a homing, a reference-edge homing, a table run.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivebus.drives.description import Reg, Trigger


@dataclass(frozen=True)
class _Word:
    """Where an address sits: its register, table entry and which word of the value."""

    reg: Reg
    index: int | None
    word: int


@dataclass(frozen=True)
class _Phase:
    """One leg of a homing: run in ``direction`` (fast or creep) until one of the edges,
    then go on with the named leg ("done": the origin)."""

    direction: int
    fast: bool
    events: tuple[tuple[str, str], ...]


@dataclass
class _RefHoming:
    """A ``reference_edge`` homing under way: its phase, direction, speeds (pulses/s), rate
    (pulses/s²) and offset (pulses)."""

    reference: str
    phase: str
    direction: float
    speed: float
    creep: float
    rate: float
    offset: float
    reversed: bool = False
    final: float | None = None
    """The counter's value where the offset travel ends (None: as it is)."""
    stop: float | None = None
    """hard_stop: the end stop's position (counter frame; None: none ahead)."""
    until: float = math.inf
    """hard_stop: when the stall on the end stop makes it the origin."""
    may_reverse: bool = True
    """A limit switch met ahead in the search reverses it (``[twin.homing]``)."""
    offset_mode: str = "origin"
    """What the offset does: origin, move or travel (chosen as the homing starts)."""


_Handler = Callable[[float], None]


@dataclass
class _TableRun:
    """A ``run_table`` under way: the trigger and value that started it, the rows, the row
    running (0-based) and whether it moves or waits."""

    trig: Trigger
    value: Any
    rows: int
    repeat: bool
    row: int = 0
    phase: str = "move"
    until: float = math.inf


@dataclass
class _Homing:
    phases: dict[str, _Phase]
    phase: str
    t_dir: float
    speed: float
    creep: float
    rate: float
    offset: float
