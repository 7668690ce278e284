"""A randomized soak of a simulated machine: concurrent commands from many tasks, judged
by the twins.

Eight motion axes of four drive kinds on two RS-485 lines and Modbus TCP take moves, jogs
with watchdogs, stops, emergency stops, cancellations, group moves, out-of-limit requests,
injected alarms and power cycles, all at once, from a mover, a stopper and a chaos task per
axis and a group task. The invariants (``SoakReport.violations`` lists what broke them):

* every call returns or raises a ``DrivebusError`` (never another exception, never hangs);
* no twin ever rests beyond its axis's soft limits (a homing searches wherever its switch
  is: from a homing until a move has completed, the axis's rest positions are not judged);
* a stop or emergency stop that returned left its twin at rest;
* at the end every axis's position is its twin's.

The test suite runs it for 30 s with a fixed seed; ``drivebus bench`` for 10 minutes.
"""

from __future__ import annotations

import contextlib
import logging
import random
from collections import Counter, deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import anyio

from drivebus.clock import monotonic
from drivebus.config import MachineConfig, parse_config
from drivebus.errors import DrivebusError, NotSupported
from drivebus.motion import Axis, AxisState, GroupMotionError, Machine, open_machine
from drivebus.sim.drive import SimDrive

__all__ = ["SoakReport", "run_soak", "soak_config"]

log = logging.getLogger(__name__)

_LIMIT = 100.0  # soft limits ±_LIMIT user units; the twins' switches far beyond them
_SWITCH = 5000.0


@dataclass
class SoakReport:
    """What a soak did and whether every invariant held."""

    seconds: float
    seed: int
    axes: int
    calls: Counter[str] = field(default_factory=Counter)
    """Calls per command."""
    outcomes: Counter[str] = field(default_factory=Counter)
    """``command: outcome`` counts: ``ok``, the error's type name, ``timed out`` (a call the
    soak gave up on through a cancel scope of its own, as a user would) or ``cancelled``
    (running when the soak ended)."""
    faults: Counter[str] = field(default_factory=Counter)
    """Faults injected into the twins: ``power cycle`` and ``alarm``."""
    violations: list[str] = field(default_factory=list)
    stops_checked: int = 0
    """Stops after which the twin was checked at rest."""
    rest_checks: int = 0
    """Twin samples checked against the soft limits while at rest."""

    def as_dict(self) -> dict[str, Any]:
        """Plain data (for JSON)."""
        return {
            "seconds": self.seconds,
            "seed": self.seed,
            "axes": self.axes,
            "calls": dict(self.calls),
            "outcomes": dict(self.outcomes),
            "faults": dict(self.faults),
            "violations": list(self.violations),
            "stops_checked": self.stops_checked,
            "rest_checks": self.rest_checks,
        }


def _axis(line: str, address: int, drive: str, **extra: Any) -> dict[str, Any]:
    return {
        "line": line, "address": address, "drive": drive, "pulses_per_rev": 1000,
        "units_per_rev": 10.0, "speed": 200.0, "accel": 2000.0, "decel": 2000.0,
        "limits": [-_LIMIT, _LIMIT], "poll": {"moving": 0.02, "idle": 0.1},
        "sim": {"limit_negative": -_SWITCH, "limit_positive": _SWITCH, **extra.pop("sim", {})},
        **extra,
    }


def soak_config(name: str = "soak") -> MachineConfig:
    """The soak machine: NT86, BHSS and CL86R on two RS-485 lines at mixed settings, two
    EPR60 on Modbus TCP, all simulated."""
    home = {"method": "home_switch_positive", "speed": 40.0, "creep": 10.0, "accel": 1000.0}
    return parse_config({
        "name": name,
        "lines": {
            "a": {"port": f"sim://{name}-a", "settings": "115200 8N1", "timeout": 0.05},
            "b": {"port": f"sim://{name}-b", "settings": "38400 8N1", "timeout": 0.05},
            "eth": {"kind": "tcp", "host": f"sim://{name}-eth", "timeout": 0.1},
        },
        "axes": {
            "a1": _axis("a", 1, "NT86", settings="115200 8N1", pulses_per_rev=4000,
                        homing=home, sim={"home_switch": 20.0}),
            "a2": _axis("a", 2, "CL86R", settings="115200 8N2", homing=home,
                        sim={"home_switch": -30.0}),
            "a3": _axis("a", 3, "BHSS", settings="19200 8E1"),
            "b1": _axis("b", 1, "NT86", settings="38400 8N1", pulses_per_rev=4000,
                        homing=home, sim={"home_switch": 5.0}),
            "b2": _axis("b", 2, "CL86R", settings="38400 8E1", homing=home,
                        sim={"home_switch": 0.5}),
            "b3": _axis("b", 3, "BHSS", settings="38400 8O1"),
            "e1": _axis("eth", 1, "EPR60", pulses_per_rev=4000, units_per_rev=360.0,
                        speed=720.0, accel=7200.0, decel=7200.0,
                        limits=[-3600.0, 3600.0]),
            "e2": _axis("eth", 2, "EPR60", pulses_per_rev=4000),
        },
    })


class _Soak:
    def __init__(self, m: Machine, seconds: float, seed: int) -> None:
        self.m = m
        self.rng = random.Random(seed)
        self.until = monotonic() + seconds
        self.report = SoakReport(seconds, seed, len(m.axes))
        self.twins: dict[str, SimDrive] = m.sim_drives  # type: ignore[assignment]
        self.began = monotonic()
        self.history: dict[str, deque[str]] = {}
        """The last commands of each axis (for the messages of violations)."""
        self.homing: set[str] = set()
        """Axes a homing may have left anywhere (until a move completes)."""

    @property
    def running(self) -> bool:
        return monotonic() < self.until

    def violation(self, text: str) -> None:
        log.error("soak violation: %s", text)
        if len(self.report.violations) < 100:
            self.report.violations.append(text)

    async def call(
        self, what: str, fn: Callable[[], Awaitable[bool | None]], axis: str | None = None
    ) -> BaseException | None:
        """Run one command; count it and its outcome; any non-drivebus error is a violation.
        ``fn`` returns False when it gave up on the command (a timeout of its own)."""
        self.report.calls[what] += 1
        if axis is not None:
            self._note(axis, what)
            if what == "home":
                # A homing searches for its switch wherever it is: soft limits do not bind
                # it (nor a stop that ends it) until a move has taken the axis back.
                self.homing.add(axis)
        log.debug("%s ...", what)
        outcome = "ok"
        try:
            with anyio.fail_after(60):
                if await fn() is False:
                    outcome = "timed out"
        except DrivebusError as exc:
            cause = exc.__cause__ if isinstance(exc, GroupMotionError) else None
            why = f" ({type(cause).__name__})" if isinstance(cause, DrivebusError) else ""
            outcome = f"{type(exc).__name__}{why}"
            return exc
        except anyio.get_cancelled_exc_class():
            outcome = "cancelled"  # by the soak, as a user would
            raise
        except TimeoutError:
            outcome = "hung"
            self.violation(f"{what} hung for 60 s")
            return None
        except Exception as exc:  # the invariant: nothing but DrivebusError
            outcome = repr(exc)
            self.violation(f"{what} raised {exc!r}")
            return exc
        finally:
            self.report.outcomes[f"{what}: {outcome}"] += 1
            if axis is not None:
                self._note(axis, f"{what} -> {outcome}")
        if axis is not None and outcome == "ok" and what.startswith(("move_to", "move_by")):
            self.homing.discard(axis)  # a move that completed took the axis back in
        return None

    def _note(self, axis: str, text: str) -> None:
        self.history.setdefault(axis, deque(maxlen=10)).append(
            f"{monotonic() - self.began:.3f} {text}")

    def target(self, ax: Axis, *, outside: bool = False) -> float:
        lo, hi = ax.config.limits or (-_LIMIT, _LIMIT)
        if outside:
            beyond = (hi - lo) * self.rng.uniform(0.01, 0.2)
            return hi + beyond if self.rng.random() < 0.5 else lo - beyond
        return self.rng.uniform(lo, hi)

    async def mover(self, name: str) -> None:
        ax = self.m.axes[name]
        rng = self.rng
        while self.running:
            pick = rng.random()
            speed = ax.config.speed * rng.uniform(0.2, 1.0)
            if ax.state is AxisState.ERROR_STOP:
                await self.recover(name)
            elif pick < 0.35:
                await self.call("move_to",
                                lambda v=speed: ax.move_to(self.target(ax), speed=v), name)
            elif pick < 0.45:
                async def cancelled(v: float = speed) -> bool:
                    with anyio.move_on_after(rng.uniform(0.0, 0.3)) as scope:
                        await ax.move_to(self.target(ax), speed=v)
                    return not scope.cancelled_caught
                await self.call("move_to (cancelled)", cancelled, name)
            elif pick < 0.55:
                distance = rng.uniform(-0.3, 0.3) * (ax.config.limits or (0, 1))[1]
                await self.call("move_by",
                                lambda d=distance, v=speed: ax.move_by(d, speed=v), name)
            elif pick < 0.6:
                await self.call("move_to (outside limits)",
                                lambda: ax.move_to(self.target(ax, outside=True)), name)
            elif pick < 0.8:
                await self.jog(ax, speed)
            elif pick < 0.85 and ax.config.homing.method is not None:
                await self.call("home", ax.home, name)
            else:
                await anyio.sleep(rng.uniform(0.2, 1.0))  # a break: room for group moves
            await anyio.sleep(rng.uniform(0.0, 0.05))

    async def jog(self, ax: Axis, speed: float) -> None:
        rng = self.rng
        sign = rng.choice((-1.0, 1.0))
        if await self.call("jog", lambda: ax.jog(sign * speed, watchdog=0.2),
                           ax.name) is not None:
            return
        for _ in range(rng.randint(0, 6)):
            await anyio.sleep(rng.uniform(0.02, 0.15))
            if rng.random() < 0.3:
                speed = ax.config.speed * rng.uniform(0.2, 1.0)
                sign = rng.choice((-1.0, 1.0))
                await self.call("jog (speed change)",
                                lambda s=sign * speed: ax.jog(s, watchdog=0.2), ax.name)
            else:
                ax.feed()
        if rng.random() < 0.5:
            await self.stop(ax, "stop")
        # else: the watchdog stops it

    async def stop(self, ax: Axis, how: str) -> None:
        twin = self.twins[ax.name]
        error = await self.call(how, ax.stop if how == "stop" else ax.halt_now, ax.name)
        if error is None:
            self.report.stops_checked += 1
            if twin.is_moving():
                self.violation(f"{ax.name}: {how}() returned while its twin still moves "
                               f"({ax.state}; after {list(self.history.get(ax.name, []))})")

    async def stopper(self, name: str) -> None:
        ax = self.m.axes[name]
        while self.running:
            await anyio.sleep(self.rng.expovariate(1 / 1.5))
            await self.stop(ax, "stop" if self.rng.random() < 0.7 else "halt_now")

    async def recover(self, name: str) -> None:
        ax, twin = self.m.axes[name], self.twins[name]
        error = await self.call("reset", ax.reset)
        if isinstance(error, NotSupported | DrivebusError) and ax.state is AxisState.ERROR_STOP:
            await self.power_cycle(name, 0.1)
            with anyio.move_on_after(5):
                async for _ in ax.watch():
                    if ax.state is not AxisState.OFFLINE and not twin.alarm_code:
                        break
            await self.call("reset", ax.reset)

    async def power_cycle(self, name: str, off: float) -> None:
        twin = self.twins[name]
        self.report.faults["power cycle"] += 1
        self._note(name, f"power off for {off:.2f} s")
        twin.power_loss()
        await anyio.sleep(off)
        twin.power_restore()

    async def chaos(self, name: str) -> None:
        rng = self.rng
        twin = self.twins[name]
        while self.running:
            await anyio.sleep(rng.expovariate(1 / 6.0))
            if not self.running:
                return
            if rng.random() < 0.5:
                self.report.faults["alarm"] += 1
                self._note(name, "alarm raised")
                twin.raise_alarm(4)
            else:
                # Off for longer than the idle poll period: a drive needs time to boot,
                # and a cycle no transaction sees would leave no trace to detect.
                await self.power_cycle(name, rng.uniform(0.15, 0.5))

    async def grouper(self) -> None:
        rng = self.rng
        names = list(self.m.axes)
        while self.running:
            await anyio.sleep(rng.uniform(0.1, 0.8))
            chosen = rng.sample(names, rng.randint(2, 4))
            with anyio.move_on_after(1.0):  # wait a moment for them to be free
                for n in chosen:
                    async for _ in self.m.axes[n].watch():
                        if self.m.axes[n].state is AxisState.STANDSTILL:
                            break
            group = self.m.group(*chosen)
            targets = {n: self.target(self.m.axes[n]) for n in chosen}
            await self.call("group move_to", lambda g=group, t=targets: g.move_to(t))

    async def monitor(self) -> None:
        """No twin rests beyond its axis's soft limits (checked every few ms)."""
        while self.running:
            for name, twin in self.twins.items():
                ax = self.m.axes[name]
                if twin.is_moving() or ax.config.limits is None or name in self.homing:
                    continue
                self.report.rest_checks += 1
                lo, hi = ax.config.limits
                pos = ax.units.from_pulses(twin.position())
                if not lo - 1e-9 <= pos <= hi + 1e-9:
                    self.violation(f"{name}: twin at rest at {pos:.4f}, beyond {lo}..{hi} "
                                   f"({ax.state}; at {monotonic() - self.began:.3f} after "
                                   f"{list(self.history.get(name, []))})")
            await anyio.sleep(0.005)

    async def finish(self) -> None:
        """Stop everything; every axis's position must be its twin's."""
        for name, ax in self.m.axes.items():
            twin = self.twins[name]
            if ax.state is AxisState.ERROR_STOP:
                await self.recover(name)
            with anyio.move_on_after(10):
                async for _ in ax.watch():
                    if ax.state is not AxisState.OFFLINE:
                        break
            with contextlib.suppress(DrivebusError):
                await ax.stop()
            try:
                st = await ax.refresh()
            except DrivebusError as exc:
                self.violation(f"{name}: cannot read the drive at the end: {exc}")
                continue
            if twin.is_moving():
                self.violation(f"{name}: twin still moving at the end")
            expected = twin.position()
            if st.position != expected:
                self.violation(f"{name}: axis at {st.position} pulses, twin at {expected}")


async def run_soak(seconds: float = 30.0, seed: int = 1, *, name: str = "soak") -> SoakReport:
    """Soak a simulated machine for ``seconds`` with a fixed ``seed``; see the module."""
    async with open_machine(soak_config(name)) as m:
        soak = _Soak(m, seconds, seed)
        with anyio.fail_after(seconds + 120):
            async with anyio.create_task_group() as tg:
                for axis in m.axes:
                    tg.start_soon(soak.mover, axis)
                    tg.start_soon(soak.stopper, axis)
                    tg.start_soon(soak.chaos, axis)
                tg.start_soon(soak.grouper)
                tg.start_soon(soak.monitor)
            await soak.finish()
        return soak.report

