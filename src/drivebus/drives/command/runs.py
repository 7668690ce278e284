"""What a procedure's run keeps: its arguments, what it read and wrote, dry or not
(``_Run``), a value to write (``_Item``), ``last.REGISTER`` (``_Last``), and the
priorities procedures run at.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from drivebus.bus import Priority
from drivebus.drives.description import Reg
from drivebus.drives.expr import Expr
from drivebus.drives.registers import Register
from drivebus.drives.values import Attrs

_PRIORITY = {"emergency": Priority.EMERGENCY, "command": Priority.COMMAND,
             "config": Priority.CONFIG, "poll": Priority.POLL}


_DEFAULT_PRIORITY = {
    "learn": Priority.CONFIG, "setup": Priority.CONFIG, "save_parameters": Priority.CONFIG,
    "stop": Priority.EMERGENCY, "emergency_stop": Priority.EMERGENCY,
}


_MAX_DEPTH = 8


class _Last:
    """``last.REGISTER``: the physical value this profile last wrote (None if never)."""

    __slots__ = ("_values",)

    def __init__(self, values: Mapping[str, Any]) -> None:
        self._values = values

    def __getattr__(self, key: str) -> Any:
        if key.startswith("_"):
            raise AttributeError(key)
        return self._values.get(key)


@dataclass
class _Run:
    """One run of a procedure: its arguments, what it read and wrote, dry or not."""

    proc: str
    args: dict[str, Any]
    dry: bool
    priority: Priority
    depth: int = 0
    values: dict[str, Any] = field(default_factory=dict)
    """Register key -> value (a ``Table`` for tables) read by this run."""
    written: dict[str, Any] = field(default_factory=dict)
    """Register (or ``key[index]``) -> physical value written by this run."""
    result: Any = None
    home: Attrs | None = None
    trace: list[tuple[str, Reg, int | None, int, str]] = field(default_factory=list)
    """(step action, register, index, raw, source expression) of every value written."""


@dataclass
class _Item:
    reg: Reg
    index: int | None
    register: Register
    value: Any
    source: Expr
    nonzero: bool
    as_raw: bool = False
    raw: int = 0
    physical: Any = None

    @property
    def key(self) -> str:
        return self.reg.key if self.index is None else f"{self.reg.key}[{self.index}]"
