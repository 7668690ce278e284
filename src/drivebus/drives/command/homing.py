"""Homing: the description's methods (by name or code), the switches each homes on or
reverses at, and ``home`` run with the method's code and extras (``home.*``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from drivebus.drives.base import HomingParams, HomingSwitches
from drivebus.drives.command.base import ProfileBase
from drivebus.drives.command.runs import _Run
from drivebus.drives.expr import Expr
from drivebus.drives.values import Attrs
from drivebus.errors import UnknownMethod


class Homing(ProfileBase):
    """Homing by the description's methods."""

    def homing_mode(self, method: str | None) -> int | None:
        """The code of homing method ``method`` (a name, or its code as digits)."""
        return self._home_method(method)[1].code

    def _home_method(self, method: str | None) -> tuple[str, Any]:
        h = self.description.homing
        if h is None:
            raise self.unsupported("home")
        name = next(iter(h.methods)) if method is None else method
        if name in h.methods:
            return name, h.methods[name]
        if isinstance(name, str) and name.isdigit():
            for n, m in h.methods.items():
                if m.code == int(name):
                    return n, m
        documented = ", ".join(f"{n} ({m.code})" if m.code is not None else n
                               for n, m in h.methods.items())
        raise UnknownMethod(str(self.unsupported(
            f"home with method {method!r}",
            f"it has no homing method {method!r}; it documents {documented}")))

    def homing_switches(self, method: str | None) -> HomingSwitches:
        """The limit switches homing with ``method`` homes on or reverses at: the method's
        ``homes_on``/``reverses_at`` (+1/-1) where it gives them, else its CiA 402
        method's (17/18 home on a limit switch; 23-30 reverse at the one ahead)."""
        _, m = self._home_method(method)
        extras = m.extras
        if "homes_on" in extras or "reverses_at" in extras:
            scope = self._scope(None)
            sides = {k: Expr.parse(v)(scope) if isinstance(v, str) else v  # on the options
                     for k, v in extras.items() if k in ("homes_on", "reverses_at")}
            return HomingSwitches(frozenset(sides.get("homes_on", ())),
                                  frozenset(sides.get("reverses_at", ())))
        return cia402_homing_switches(m.cia402)

    def _home_attrs(self, args: Mapping[str, Any]) -> Attrs:
        name, m = self._home_method(args.get("method"))
        return Attrs("home", {"name": name, "method": name, "code": m.code,
                              "cia402": m.cia402, **m.extras})

    def _homing_args(self, params: HomingParams) -> dict[str, Any]:
        return {"method": params.method, "speed": params.speed_rpm,
                "creep": params.creep_rpm, "accel": params.accel_rps2,
                "offset": params.offset}

    async def start_homing(self, params: HomingParams) -> None:
        """The description's ``home`` with the method's code and extras as ``home.*``.
        A method that sets the position at once (``behaviour = "set"``) has homed when
        the procedure is done: ``homed_here`` says so where no register does."""
        _, m = self._home_method(params.method)
        self.homed_here = False
        await self.run("home", **self._homing_args(params))
        self.homed_here = m.behaviour == "set"

    def check_homing(self, params: HomingParams) -> None:
        """The method known, and what ``home`` writes within range (a dry run)."""
        proc_d = self.description.procedures.get("home")
        args = {**{p.name: p.default for p in (proc_d.params if proc_d else [])},
                **self._homing_args(params)}
        proc = self._procedure("home", args)
        self._dry(proc, _Run("home", args, True, self._priority("home", proc),
                             home=self._home_attrs(args)))


def cia402_homing_switches(method: int | None) -> HomingSwitches:
    """The limit switches CiA 402 homing method ``method`` homes on or reverses at."""
    if method in (1, 17):
        return HomingSwitches(homes_on=frozenset({-1}))
    if method in (2, 18):
        return HomingSwitches(homes_on=frozenset({1}))
    if method in (7, 8, 9, 10, 23, 24, 25, 26):
        return HomingSwitches(reverses_at=frozenset({1}))
    if method in (11, 12, 13, 14, 27, 28, 29, 30):
        return HomingSwitches(reverses_at=frozenset({-1}))
    return HomingSwitches()
