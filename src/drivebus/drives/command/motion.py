"""The motion commands a profile offers (``DriveProfile``): enable, disable, moves, speed
runs, stops, alarms, zeroing, saving, a retarget, and the speed and ramps the drive's
registers round a move to (``quantize``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from typing import Any

from drivebus.bus import Priority
from drivebus.drives.base import MoveParams
from drivebus.drives.command.base import ProfileBase
from drivebus.drives.command.runs import _Run
from drivebus.drives.description import Reg
from drivebus.drives.expr import Unknown
from drivebus.drives.registers import Register
from drivebus.drives.units import Kind
from drivebus.errors import ConfigError, LimitViolation, NotSupported


class Commands(ProfileBase):
    """The motion commands, each the description's procedure."""

    async def enable(self) -> None:
        """The description's ``enable``."""
        await self.run("enable")

    async def disable(self) -> None:
        """The description's ``disable``."""
        await self.run("disable")

    def _move_args(self, target: int | None, params: MoveParams, name: str) -> dict[str, Any]:
        key = "distance" if name == "move_relative" else "target"
        return {key: target, "speed": params.speed_rpm, "accel": params.accel_rps2,
                "decel": params.decel_rps2}

    def _dry_trace(self, name: str, args: dict[str, Any]) -> list[tuple[str, Reg, int | None,
                                                                         int, str]]:
        proc = self._procedure(name, args)
        run = _Run(name, args, True, Priority.COMMAND)
        self._dry(proc, run)
        return run.trace

    def check_move(self, params: MoveParams, position: int = 0) -> None:
        """Range-check what a move to ``position`` with ``params`` would write (no I/O)."""
        self._dry_trace("move_absolute", self._move_args(position, params, "move_absolute"))

    def quantize(self, params: MoveParams) -> MoveParams:
        """The speed and ramps the drive runs after its registers' rounding.

        A planner asks this hundreds of times per move: the registers that take the speed
        and ramps are found once (a dry run of ``move_absolute``), then each call only
        rounds through their codecs; a description whose move writes them otherwise than
        as given is quantized by a dry run each time."""
        recipe = self.__dict__.get("_quantize_recipe", ())
        if recipe == ():  # not found yet: from these values, if the drive takes them
            recipe = self._find_quantize_recipe(params)
            if recipe == ():
                return self._quantize_by_dry_run(params)
            self.__dict__["_quantize_recipe"] = recipe
        if recipe is None:
            return self._quantize_by_dry_run(params)
        return self._quantize_by(recipe, params)

    def _quantize_by(self, recipe: Sequence[tuple[str, Reg, Register]],
                     params: MoveParams) -> MoveParams:
        """``params`` rounded through the registers of ``recipe`` (speeds before ramps)."""
        given = {"speed": abs(params.speed_rpm), "accel": params.accel_rps2,
                 "decel": params.decel_rps2}
        out = dict(given)
        ppr = self.pulses_per_rev
        try:
            for name, reg, register in recipe:
                codec = reg.codec
                ref = out["speed"] if codec.kind is Kind.RAMP else None
                raw = codec.to_raw(register, given[name], ppr=ppr, ref_rpm=ref)
                v = codec.to_physical(raw, ppr=ppr, ref_rpm=ref)
                if isinstance(v, int | float) and math.isfinite(v):
                    out[name] = abs(float(v))
        except (LimitViolation, NotSupported):
            return params
        return MoveParams(out["speed"], out["accel"], out["decel"])

    def _find_quantize_recipe(
        self, params: MoveParams
    ) -> tuple[tuple[str, Reg, Register], ...] | tuple[()] | None:
        """The registers ``move_absolute`` writes the speed and ramps to, as given (not
        through an expression), speeds first; None if they cannot be found that way, or
        if rounding through them disagrees with a dry run on values near ``params``;
        ``()`` if the drive does not take ``params`` (ask again with others)."""
        recipe: list[tuple[str, Reg, Register]] = []
        try:
            trace = self._dry_trace("move_absolute",
                                    self._move_args(0, params, "move_absolute"))
        except LimitViolation:
            return ()
        except (NotSupported, ConfigError, Unknown):
            return None
        for _, reg, index, _raw, source in trace:
            text = source.replace(" ", "")
            name = text.removeprefix("abs(").removesuffix(")")
            if reg.codec.kind not in (Kind.SPEED, Kind.ACCEL, Kind.RAMP):
                continue
            if name in ("speed", "accel", "decel") and text in (name, f"abs({name})"):
                recipe.append((name, reg, reg.at(index)))
            elif re.search(r"\b(speed|accel|decel)\b", text):
                return None  # written through an expression: only a dry run knows
            continue  # another value (a start speed from an option): not the move's
        recipe.sort(key=lambda r: r[1].codec.kind is Kind.RAMP)
        for f in (1.0, 0.93, 1.07, 0.71):
            sample = MoveParams(params.speed_rpm * f, params.accel_rps2 / f,
                                params.decel_rps2 * f)
            if self._quantize_by(recipe, sample) != self._quantize_by_dry_run(sample):
                return None
        return tuple(recipe)

    def _quantize_by_dry_run(self, params: MoveParams) -> MoveParams:
        """``quantize`` by running ``move_absolute`` dry and reading back what it wrote."""
        try:
            trace = self._dry_trace("move_absolute", self._move_args(0, params, "move_absolute"))
        except (LimitViolation, NotSupported):
            return params
        speed = abs(params.speed_rpm)
        out = {"speed": speed, "accel": params.accel_rps2, "decel": params.decel_rps2}
        written: dict[str, float] = {}
        # Speeds first: a ramp time was encoded against the speed as written (rounded).
        for _, reg, _index, raw, source in sorted(
                trace, key=lambda t: t[1].codec.kind is Kind.RAMP):
            name = source.replace("abs(", "").rstrip(")").strip()
            if name not in out or reg.codec.kind not in (Kind.SPEED, Kind.ACCEL, Kind.RAMP):
                continue
            ref = None
            if reg.codec.kind is Kind.RAMP:
                ref = written.get("speed", speed)
            v = reg.codec.to_physical(raw, ppr=self.pulses_per_rev, ref_rpm=ref)
            if isinstance(v, int | float) and math.isfinite(v):
                written[name] = abs(float(v))
        for name, v in written.items():
            out[name] = v
        return MoveParams(out["speed"], out["accel"], out["decel"])

    async def move_absolute(self, position: int, params: MoveParams) -> None:
        """The description's ``move_absolute``."""
        await self.run("move_absolute", **self._move_args(position, params, "move_absolute"))

    async def prepare_absolute(self, position: int, params: MoveParams) -> None:
        """``move_absolute`` up to its step marked ``start``."""
        args = self._move_args(position, params, "move_absolute")
        proc = self._procedure("move_absolute", args)
        if not any(s.start for s in proc.steps):
            await super().prepare_absolute(position, params)
            return
        self._dry(proc, _Run("move_absolute", dict(args), True, Priority.COMMAND))
        run = _Run("move_absolute", dict(args), False, Priority.COMMAND)
        await self._steps(proc.steps, run, stop_at_start=True)
        self._prepared_run = run

    async def start_absolute(self) -> None:
        """The rest of the prepared ``move_absolute``, from its step marked ``start``."""
        run = getattr(self, "_prepared_run", None)
        if run is None:
            await super().start_absolute()
            return
        proc = self._procedure("move_absolute", run.args)
        await self._steps(proc.steps, run, from_start=True)

    async def move_relative(self, distance: int, params: MoveParams) -> None:
        """The description's ``move_relative``."""
        await self.run("move_relative", **self._move_args(distance, params, "move_relative"))

    async def speed_run(self, speed_rpm: float, accel_rps2: float, decel_rps2: float) -> None:
        """The description's ``speed_run`` (signed speed)."""
        await self.run("speed_run", speed=speed_rpm, accel=accel_rps2, decel=decel_rps2)

    def stop_takes_decel(self) -> bool:
        """Whether the description's stop honours a deceleration: its ``takes``, else
        whether its steps use ``decel`` (or pass it to a procedure they call)."""
        proc = self._steps_of("stop")
        return proc is not None and proc.honours("decel")

    def check_stop(self, decel_rps2: float | None) -> None:
        """A deceleration the stop cannot honour, or one beyond its register's range, is
        refused before anything is sent (``NotSupported``, ``LimitViolation``)."""
        super().check_stop(decel_rps2)
        if decel_rps2 is not None:
            self.dry_run("stop", decel=decel_rps2)

    async def stop(self, decel_rps2: float | None = None) -> None:
        """The description's ``stop`` (a deceleration it cannot honour is refused first)."""
        self.check_stop(decel_rps2)
        await self.run("stop", decel=decel_rps2)

    async def emergency_stop(self) -> None:
        """The description's ``emergency_stop``."""
        await self.run("emergency_stop")

    async def clear_alarm(self) -> None:
        """The description's ``clear_alarm``."""
        await self.run("clear_alarm")

    async def zero_position(self) -> None:
        """The description's ``zero_position``."""
        await self.run("zero_position")

    async def save_parameters(self) -> None:
        """The description's ``save_parameters``."""
        await self.run("save_parameters")

    async def retarget_absolute(self, position: int, params: MoveParams) -> None:
        """The description's ``retarget_absolute`` (``[programs] retarget`` says how the
        drive takes it); without one, ``NotSupported`` with ``[programs] no_retarget``."""
        if "retarget_absolute" not in self.description.procedures:
            await super().retarget_absolute(position, params)
            return
        await self.run("retarget_absolute",
                       **self._move_args(position, params, "retarget_absolute"))
