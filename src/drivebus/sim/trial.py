"""``drivebus drive try``: run a drive description against its own simulated twin.

The way to check a description before touching hardware: the profile its engine makes
drives the twin built from the same file, on a simulated line, through enable, moves, a
stop, a speed run, an emergency stop, homing, an alarm, disable and a power cycle. Each
step is judged by what the *twin* did (where it is, whether it moves), not by what the
profile decoded, so a wrong address, word order, unit or status bit shows up as a
failed step with what was expected and what happened.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass

import anyio

from drivebus.drives.base import DriveProfile, MoveParams
from drivebus.drives.cia402 import HomeSwitch, homing_method
from drivebus.drives.description import Description, HomingMethod
from drivebus.drives.engine import profile_class
from drivebus.drives.status import DriveStatus
from drivebus.errors import ArgumentError, DrivebusError, LimitViolation, NotSupported
from drivebus.settings import LineSettings
from drivebus.sim.described import twin_of
from drivebus.sim.drive import TwinSetup
from drivebus.sim.harness import sim_bus
from drivebus.sim.twins import coded_twin

__all__ = ["TrialStep", "format_trial", "try_description"]

_SPEEDS = (600.0, 300.0, 120.0, 60.0, 30.0, 10.0)
_RATES = (100.0, 50.0, 200.0, 20.0, 500.0, 10.0, 1000.0, 5.0)
_TIMEOUT = 10.0


@dataclass(frozen=True)
class TrialStep:
    """One step of a trial: its name, "pass", "FAIL" or "skip", and what was seen."""

    name: str
    result: str
    detail: str = ""

    @property
    def failed(self) -> bool:
        """True for a failed step."""
        return self.result == "FAIL"


class _Failed(Exception):
    pass


def _settings(d: Description) -> LineSettings | None:
    if d.link.protocol != "rtu":
        return None
    baud = max(d.link.baud_rates) if d.link.baud_rates else 115200
    fmt = d.link.formats[0] if d.link.formats else "8N1"
    for rule in d.link.format_rules:
        if baud in rule.baud_rates:
            fmt = rule.formats[0]
    return LineSettings.parse(fmt, baudrate=baud)


def _params(profile: DriveProfile) -> MoveParams:
    """The fastest modest move the drive accepts."""
    last: Exception | None = None
    for speed in _SPEEDS:
        for rate in _RATES:
            p = MoveParams(speed, rate, rate)
            try:
                profile.check_move(p)
            except (LimitViolation, NotSupported) as exc:
                last = exc
                continue
            return p
    raise _Failed("no speed of 10..600 rpm with a ramp of 5..1000 rev/s² fits its registers"
                  f" (the last refused: {last})")


_FIELDS = {"enabled": ("enabled",), "in position at rest": ("in_position", "moving"),
           "moving": ("moving",), "at rest after the stop": ("moving",),
           "at rest": ("moving",), "homed at rest": ("homed", "moving"),
           "disabled": ("enabled",)}
"""The status fields each wait of the trial judges by."""

_MEANINGS = {"enabled": '"enabled"', "moving": '"moving" (or "at_rest")',
             "in_position": '"in_position" (or "reached": a move ran to its end)',
             "homed": '"homed"'}


def key_hint(d: Description, fields: tuple[str, ...]) -> str:
    """What to add to description ``d`` so that the status shows ``fields``: a status
    field it does not decode, or bits the twin cannot compute (no ``means``)."""
    if d.drive.engine == "cia402":
        return ""
    hints: list[str] = []
    exprs = d.status_exprs
    for field in fields:
        e = exprs.get(field)
        if e is None:
            hints.append(f"[status] decodes no {field}: add means = {_MEANINGS[field]} to "
                         f"the bit that shows it, or [status] {field} = \"...\"")
            continue
        for path in sorted(e.paths):
            key, _, bit = path.partition(".")
            reg = d.regs.get(key)
            b = reg.d.bits.get(bit) if reg is not None else None
            if b is not None and b.means is None and b.twin is None:
                hints.append(f"status.{field} reads {path}, which the twin cannot compute: "
                             f"add means = {_MEANINGS.get(field, repr(field))} (or twin = "
                             f"\"...\") to registers.{key}.bits.{bit}")
    return ("; to fix: " + "; ".join(hints)) if hints else ""


async def _wait(profile: DriveProfile, cond: Callable[[DriveStatus], bool], what: str,
                timeout: float = _TIMEOUT) -> DriveStatus:
    st: DriveStatus | None = None
    try:
        with anyio.fail_after(timeout):
            while True:
                st = await profile.read_status()
                if cond(st):
                    return st
                await anyio.sleep(0.01)  # the poll period; the read is the condition
    except TimeoutError:
        d = getattr(profile, "description", None)
        hint = key_hint(d, _FIELDS.get(what, ())) if isinstance(d, Description) else ""
        raise _Failed(f"{what} did not happen within {timeout:g} s (last status: "
                      f"{_brief(st)}){hint}") from None


def _brief(st: DriveStatus | None) -> str:
    if st is None:
        return "none"
    flags = [k for k in ("enabled", "moving", "in_position", "homed", "homing", "alarm",
                         "limit_positive", "limit_negative") if getattr(st, k)]
    return f"{', '.join(flags) or 'no flags'}; position {st.position}"


async def try_description(d: Description, *, address: int | None = None) -> list[TrialStep]:
    """Run description ``d`` against its twin (the generic twin of ``d``, or the twin
    written as code of a built-in family that has one); one ``TrialStep`` per step."""
    profile_cls = profile_class(d)
    twin_cls = coded_twin(d.drive.family) or twin_of(d)
    address = address or max(min(profile_cls.addresses), 1)
    settings = _settings(d)
    ppr = _trial_ppr(d, profile_cls.pulses_per_rev_allowed)
    setup = TwinSetup(home_switch=1.5 * ppr, limit_negative=-_LIMIT * ppr,
                      limit_positive=_LIMIT * ppr)
    twin = twin_cls(address, settings, setup)
    steps: list[TrialStep] = []
    line = settings or twin.settings or LineSettings()  # a TCP drive: its twin's serial
    async with sim_bus([twin], line, timeout=0.2, retries=1) as (_, bus):
        profile = profile_cls(bus.slave(address, settings=settings), pulses_per_rev=ppr)
        state: dict[str, MoveParams] = {}

        async def step(name: str, fn: Callable[[], Awaitable[str]],
                       procedure: str | None = None) -> None:
            if procedure is not None:
                try:
                    profile.check_supported(procedure)
                except NotSupported as exc:
                    steps.append(TrialStep(name, "skip", str(exc)))
                    return
            try:
                detail = await fn()
            except _Failed as exc:
                steps.append(TrialStep(name, "FAIL", str(exc)))
            except (DrivebusError, TimeoutError, ValueError) as exc:
                steps.append(TrialStep(name, "FAIL", f"{type(exc).__name__}: {exc}"))
            else:
                steps.append(TrialStep(name, "pass", detail))

        async def open_() -> str:
            st = await profile.read_status()
            ident = await profile.read_identity()
            own = profile.is_own_identity(ident) if ident.raw else None
            if own is False:
                raise _Failed(f"identify.match does not hold on the twin ({ident.raw})")
            return f"status {_brief(st)}" + (f"; identified as {ident.model}" if own else "")

        async def setup_() -> str:
            await profile.setup()
            lost = await profile.lost_settings()
            if lost:
                raise _Failed(f"read back after setup differs: {'; '.join(lost)}")
            state["move"] = _params(profile)
            return f"{len(profile.volatile_settings())} volatile settings written and read back"

        async def enable() -> str:
            await profile.enable()
            st = await _wait(profile, lambda s: s.enabled, "enabled")
            if not twin.enabled:
                raise _Failed("the status says enabled but the twin is not")
            return _brief(st)

        def move() -> MoveParams:
            return state.get("move") or _params(profile)

        async def absolute() -> str:
            target = twin.position() + 2 * ppr
            await profile.move_absolute(target, move())
            st = await _wait(profile, lambda s: s.in_position and not s.moving,
                             "in position at rest")
            if twin.position() != target or st.position != target:
                raise _Failed(f"asked {target}: the twin is at {twin.position()}, the status "
                              f"says {st.position}")
            return f"at {target} pulses ({move().speed_rpm:g} rpm)"

        async def relative() -> str:
            start = twin.position()
            await profile.move_relative(-ppr, move())
            st = await _wait(profile, lambda s: s.in_position and not s.moving,
                             "in position at rest")
            if twin.position() != start - ppr or st.position != twin.position():
                raise _Failed(f"asked {start - ppr}: the twin is at {twin.position()}, the "
                              f"status says {st.position}")
            return f"by {-ppr} pulses to {twin.position()}"

        async def stop() -> str:
            start = twin.position()
            await profile.move_relative(4 * ppr, move())
            await _wait(profile, lambda s: s.moving, "moving")
            await profile.stop()
            st = await _wait(profile, lambda s: not s.moving, "at rest after the stop")
            if twin.is_moving():
                raise _Failed("the status says at rest but the twin moves")
            if not start < twin.position() < start + 4 * ppr:
                raise _Failed(f"the twin is at {twin.position()}: the stop did not cut the "
                              f"move short")
            return f"stopped at {st.position}"

        async def run() -> str:
            p = move()
            await profile.speed_run(p.speed_rpm, p.accel_rps2, p.decel_rps2)
            await _wait(profile, lambda s: s.moving, "moving")
            await anyio.sleep(min(0.2, p.speed_rpm / 60 / p.accel_rps2 + 0.05))
            v = twin.speed_rpm()
            if not v > 0:
                raise _Failed(f"the twin turns at {v:g} rpm, not forwards")
            await profile.stop()
            await _wait(profile, lambda s: not s.moving, "at rest after the stop")
            return f"ran at {v:g} rpm, then stopped"

        async def estop() -> str:
            p = move()
            try:
                profile.check_supported("speed_run")
            except NotSupported:  # a drive without speed runs: stop a long move instead
                await profile.move_relative(-4 * ppr, p)
            else:
                await profile.speed_run(-p.speed_rpm, p.accel_rps2, p.decel_rps2)
            await _wait(profile, lambda s: s.moving, "moving")
            await profile.emergency_stop()
            st = await _wait(profile, lambda s: not s.moving, "at rest", timeout=2.0)
            if twin.is_moving():
                raise _Failed("the twin still moves")
            return f"at rest at {st.position}"

        async def home() -> str:
            """Every homing method the description names, one after the other (before:
            the first only, so a wrong CiA 402 number or a method the twin cannot end
            in any other passed ``try``)."""
            p = move()
            assert d.homing is not None
            done = []
            for name, method in d.homing.methods.items():
                if not (await profile.read_status()).enabled:  # a quick stop may disable it
                    await profile.enable()
                twin.set_home_shape(*_home_shape(method, ppr))  # the switch it expects
                where, origin = _origin(method, ppr, twin.physical_position())
                # a gentle homing ramp (0.1 s to 120 rpm): drives with a minimum ramp time
                try:
                    await profile.home(name, speed_rpm=min(p.speed_rpm, 120.0),
                                       creep_rpm=max(min(p.speed_rpm, 120.0) / 4, 1.0),
                                       accel_rps2=min(p.accel_rps2, 20.0))
                except NotSupported as e:  # refused before any frame: it says why
                    done.append(f"{name}: refused ({e})")
                    continue
                st = await _wait(profile,
                                 lambda s: s.homed and not s.moving and not s.homing,
                                 f"{name}: homed at rest", timeout=3 * _TIMEOUT)
                if origin is None:
                    done.append(f"{name}: homed; position {st.position}")
                    continue
                off = twin.physical_position() - origin
                if abs(off) > (1.5 if _uses_index(method) else 0.5) * ppr:
                    raise _Failed(f"{name}: homed {off:+.0f} pulses away from {where}")
                done.append(f"{name}: homed {off:+.0f} pulses from {where}; position "
                            f"{st.position}")
            return "; ".join(done)

        async def alarm() -> str:
            code = _alarm_code(d)
            twin.raise_alarm(code)
            st = await profile.read_status()
            if not st.alarm:
                raise _Failed(f"the twin latched alarm {code}; the status shows no alarm")
            text = st.alarm_text
            try:
                profile.check_supported("clear_alarm")
            except NotSupported:
                twin.alarm_code = 0
                return f"shown as {st.alarm_code} {text!r}; cannot be cleared over the bus"
            await profile.clear_alarm()
            st = await profile.read_status()
            if st.alarm:
                raise _Failed("clear_alarm left the alarm latched")
            return f"shown as {st.alarm_code or code} {text!r}, then cleared"

        async def disable() -> str:
            await profile.disable()
            await _wait(profile, lambda s: not s.enabled, "disabled")
            if twin.enabled:
                raise _Failed("the status says disabled but the twin is enabled")
            return "released"

        async def power() -> str:
            twin.power_loss()
            twin.power_restore()
            lost = await profile.lost_settings()
            await profile.setup()
            again = await profile.lost_settings()
            if again:
                raise _Failed(f"after setup again: {'; '.join(again)}")
            return ("lost " + "; ".join(lost)) if lost else "nothing volatile was lost"

        await step("open", open_)
        await step("setup", setup_)
        await step("enable", enable, "enable")
        await step("move absolute", absolute, "move_absolute")
        await step("move relative", relative, "move_relative")
        await step("stop", stop, "stop")
        await step("speed run (jog)", run, "speed_run")
        await step("emergency stop", estop, "emergency_stop")
        await step("home", home, "home")
        await step("alarm", alarm)
        await step("disable", disable, "disable")
        await step("power cycle", power)
    return steps


_LIMIT = 8.0
"""The twin's limit switches sit this many revolutions either side of 0."""


def _trial_ppr(d: Description, allowed: object) -> int:
    """The pulses/rev to try: another than the register's factory value where the drive
    allows one, so that the power cycle shows the setup lost."""
    ppr = d.units.pulses_per_rev
    if ppr.reg is None:
        return ppr.default
    factory = d.regs[ppr.reg].codec.to_physical(d.regs[ppr.reg].default_at(None))
    for candidate in (4000, 2000, 10000, 1000, 8000, 5000, 1600, 3200, 800):
        if candidate != factory and candidate in allowed:  # type: ignore[operator]
            return candidate
    return ppr.default


def _cia402_switch(m: HomingMethod) -> HomeSwitch | None:
    """The home switch CiA 402 method ``m`` expects (None: none, or not a CiA 402 one)."""
    if m.cia402 is None:
        return None
    try:
        return homing_method(m.cia402).home_switch
    except ArgumentError:
        return None


def _home_shape(m: HomingMethod, ppr: int) -> tuple[str | None, float | None]:
    """The trial twin's home switch for method ``m``: a cam on the side the method
    expects, or a dog of one revolution from 1.5 revolutions where it homes on an edge
    of a switch over part of the travel (else the twin's own)."""
    switch = _cia402_switch(m)
    if switch is HomeSwitch.POSITIVE:
        return "positive", None
    if switch is HomeSwitch.NEGATIVE:
        return "negative", None
    if switch in (HomeSwitch.LOWER_EDGE, HomeSwitch.UPPER_EDGE):
        return None, float(ppr)
    return None, None


def _origin(m: HomingMethod, ppr: int, start: float) -> tuple[str, float | None]:
    """Where homing method ``m`` (its CiA 402 method, or its reference input) puts the
    origin on the trial's twin."""
    if m.behaviour == "reference_edge":
        return {"home_switch": ("the home switch's edge", 1.5 * ppr),
                "limit_positive": ("the positive limit switch", _LIMIT * ppr),
                "limit_negative": ("the negative limit switch", -_LIMIT * ppr),
                }[m.reference or "home_switch"]
    method = m.cia402
    if method in (1, 17):
        return "the negative limit switch", -_LIMIT * ppr
    if method in (2, 18):
        return "the positive limit switch", _LIMIT * ppr
    if method is not None and 3 <= method <= 30:
        if _cia402_switch(m) is HomeSwitch.UPPER_EDGE:
            return "the home switch's upper edge", 2.5 * ppr
        return "the home switch's edge", 1.5 * ppr
    if method in (33, 34, 35, 37):
        return "where it stood", start
    return "", None


def _uses_index(m: HomingMethod) -> bool:
    """Whether ``m`` ends on the encoder's index pulse (its CiA 402 method's): the next
    one after its reference, up to a revolution on."""
    return m.behaviour != "reference_edge" and m.cia402 is not None and \
        homing_method(m.cia402).index_pulse


def _alarm_code(d: Description) -> int:
    """An alarm code to raise: one the clear-alarm command clears, where the description
    says which do."""
    if d.alarms is not None and d.alarms.texts:
        cleared = [c for c in d.alarms.texts if d.alarms.clears.get(c, "command") == "command"]
        return (cleared or list(d.alarms.texts))[0]
    return 1


def format_trial(family: str, steps: list[TrialStep]) -> str:
    """The trial as a table with a summary line."""
    width = max(len(s.name) for s in steps)
    lines = [f"{family}: its description against its simulated twin", ""]
    for s in steps:
        lines.append(f"  {s.name:<{width}}  {s.result:<4}  {s.detail}")
    failed = sum(s.failed for s in steps)
    skipped = sum(s.result == "skip" for s in steps)
    passed = len(steps) - failed - skipped
    lines += ["", f"{passed} passed, {failed} failed, {skipped} skipped"]
    return "\n".join(lines)
