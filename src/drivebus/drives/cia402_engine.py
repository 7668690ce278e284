"""The CiA 402 engine: a ``DriveProfile`` for drives that map the CiA 402 objects onto
Modbus registers, run from their description.

The description says where each object is (``object = "controlword"`` on a register, or
an address rule in ``[cia402]``) and in which units; the engine runs the profile with the
pure logic of ``drivebus.drives.cia402``: the device control state machine (shutdown,
switch on, enable operation, fault reset as a rising edge), profile position with the
new-set-point handshake, profile velocity, homing with the homing method's number, halt
for a decelerating stop and quick stop (or halt) for an emergency stop. A common procedure
the description itself defines (``[procedures.enable]``, say) replaces the engine's, and
the description's own procedures, ``setup`` and ``learn`` run as in the command engine.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from functools import cached_property
from typing import Any, ClassVar

import anyio

from drivebus.bus import Priority
from drivebus.clock import monotonic
from drivebus.drives.base import DriveProfile, HomingParams, MoveParams
from drivebus.drives.cia402 import (
    COMMAND_WORDS,
    MAX_STEPS,
    Command,
    Controlword,
    DigitalInput,
    HomingStatus,
    Mode,
    SetPointHandshake,
    State,
    StatuswordError,
    decode_state,
    homing_status,
    next_step,
)
from drivebus.drives.command.profile import DescribedProfile
from drivebus.drives.command.reads import plan_reads
from drivebus.drives.command.status import polled_raw, raw_values
from drivebus.drives.description import Reg
from drivebus.drives.status import DriveStatus
from drivebus.drives.values import Attrs, Unread
from drivebus.errors import LimitViolation, StateError, TransactionError

__all__ = ["STATUS_OBJECTS", "Cia402Profile"]

STATUS_OBJECTS = ("statusword", "modes_of_operation_display", "position_actual_value",
                  "velocity_actual_value", "error_code", "digital_inputs")
"""The objects the status poll reads, where the description maps them."""

log = logging.getLogger(__name__)

_ENABLED = COMMAND_WORDS[Command.ENABLE_OPERATION]
_HALTED = _ENABLED | Controlword.HALT
"""Enable operation with halt set: Operation enabled, the axis held where it is."""


class Cia402Profile(DescribedProfile):
    """A profile that runs a CiA 402 drive's description."""

    _status_objects: ClassVar[tuple[str, ...]]

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._last_cw: int | None = None
        self._homing = False
        self._homed = False
        self._velocity_set = False
        """A speed run of this session left a target velocity (60FFh) other than 0."""

    @cached_property
    def tracked(self) -> frozenset[str]:
        """``homed``, unless a polled bit the drive keeps says it (the Lexium 32's ref_ok):
        the statusword tells a homing's end only in homing mode, so the engine records it."""
        polled = (reg for reg, _ in self._status_plan.regs)
        bits = (b for reg in polled for b in reg.d.bits.values())
        return frozenset() if any(b.means == "homed" for b in bits) else frozenset({"homed"})

    def restarted(self) -> None:
        """No homing was done here since the drive started again."""
        super().restarted()
        self._homing = self._homed = False

    # -- objects ---------------------------------------------------------------------------

    def _obj(self, name: str) -> Reg:
        reg = self.description.objects.get(name)
        if reg is None:
            raise self.unsupported(f"use the CiA 402 object {name}",
                                   "its description maps no register to it")
        return reg

    def _raw(self, name: str, value: float | int, ref: float | None = None) -> int:
        reg = self._obj(name)
        return reg.codec.to_raw(reg.register, value, ppr=self.pulses_per_rev, ref_rpm=ref)

    async def _write_objects(self, values: Sequence[tuple[str, float | int]], *,
                             priority: Priority = Priority.COMMAND,
                             idempotent: bool = True) -> None:
        """Write objects (values in drive units), all range-checked first; objects of one
        of ``[cia402] blocks`` side by side go in one FC16, every other object in a request
        of its own (a drive answers a write across objects its manual keeps apart with an
        exception)."""
        c = self.description.cia402
        items = [(self._obj(n).register, self._raw(n, v), n) for n, v in values]
        groups: list[list[tuple[Any, int]]] = []
        block: int | None = None
        for r, raw, name in sorted(items, key=lambda x: (x[0].address, x[0].offset)):
            mine = c.block_of(name) if c is not None else None
            if groups and r.follows(groups[-1][-1][0]) and (
                    r.objects or (mine is not None and mine == block)):
                groups[-1].append((r, raw))  # a block, or the sub-indices of one object
                continue
            groups.append([(r, raw)])
            block = mine
        for group in groups:
            if len(group) == 1:
                await self.write(group[0][0], group[0][1], priority=priority,
                                 idempotent=idempotent)
            else:
                await self.write_block(group, priority=priority, idempotent=idempotent)

    async def _controlword(self, word: int, *, priority: Priority = Priority.COMMAND,
                           idempotent: bool = False) -> None:
        await self.write(self._obj("controlword").register, word, priority=priority,
                         idempotent=idempotent)
        self._last_cw = word

    async def _statusword(self, priority: Priority = Priority.COMMAND) -> int:
        return await self.read(self._obj("statusword").register, priority=priority)

    async def _state(self, priority: Priority = Priority.COMMAND) -> tuple[State, int]:
        sw = await self._statusword(priority)
        try:
            return decode_state(sw), sw
        except StatuswordError as exc:
            raise StateError(f"{self.family}: {exc}") from None

    async def goto(self, goal: State) -> None:
        """Walk the state machine to ``goal`` (bounded: each step is confirmed within the
        description's timeout, and no more steps than the profile can need). Enable
        operation goes with halt set: Operation enabled holds the axis (a set-point a halt
        interrupted does not resume); the next motion command clears halt as it starts."""
        timeout = self._timeout
        for _ in range(MAX_STEPS + 2):
            state, _ = await self._state()
            step = next_step(state, goal, self._last_cw)
            if step is None:
                return
            if step.controlword is not None:
                word = step.controlword
                if step.command is Command.ENABLE_OPERATION:
                    word |= Controlword.HALT
                await self._controlword(word, idempotent=True)
            try:
                with anyio.fail_after(timeout):
                    while True:
                        state, _ = await self._state()
                        if state is step.expect or state is goal:
                            break
                        await anyio.sleep(0.005)  # the poll period; the read decides
            except TimeoutError:
                raise StateError(
                    f"{self.family}: {step.command or 'waiting'} did not lead from {state} to "
                    f"{step.expect} within {timeout:g} s") from None
        state, _ = await self._state()
        raise StateError(f"{self.family}: the drive did not reach {goal} (it is {state})")

    @property
    def _timeout(self) -> float:
        c = self.description.cia402
        return c.timeout if c is not None else 1.0

    def _described(self, name: str) -> bool:
        return name in self.description.procedures

    # -- status ----------------------------------------------------------------------------

    async def read_status(self, *, priority: Priority = Priority.POLL) -> DriveStatus:
        """The mapped status objects in as few reads as the drive allows."""
        if not self._learned and self.description.status.learn_first:
            await self.learn(priority=max(priority, Priority.CONFIG))  # (as the engine's)
        requested = monotonic()
        raw_words: dict[str, list[int]] = {}
        values = await self._poll_values(self._status_plan, priority, raw_words)
        await self._read_due_signals(priority)
        return self.decode_status(values, raw_words, requested_at=requested)

    def decode_status(self, values: Mapping[str, Any],
                      raw_words: Mapping[str, list[int]] | None = None, *,
                      requested_at: float | None = None) -> DriveStatus:
        """A ``DriveStatus`` from the objects read (the description's ``[status]`` fields,
        where it gives them, replace the engine's). The homing under way is judged only
        by a status requested after the last write's reply (``fresh``): a poll that left
        before the homing's start cannot end it."""
        d = self.description
        obj = {n: values.get(r.key) for n, r in d.objects.items()}
        sw = int(obj.get("statusword") or 0)
        try:
            state: State | None = decode_state(sw)
        except StatuswordError:
            state = None
        mode = obj.get("modes_of_operation_display")
        if mode is None:  # no display mapped: the mode written is the mode
            mode = obj.get("modes_of_operation")
        velocity = obj.get("velocity_actual_value")
        reached = bool(sw & 0x0400)
        enabled = state is State.OPERATION_ENABLED
        fault = state in (State.FAULT, State.FAULT_REACTION_ACTIVE)
        homing_mode = mode is not None and int(mode) == Mode.HOMING
        hs = homing_status(sw) if homing_mode else None
        if not self.fresh(requested_at):
            pass  # older than the last command's reply: it tells nothing of the homing
        elif self._homing and hs is not None:
            if hs is HomingStatus.COMPLETED:
                self._homing, self._homed = False, True
            elif hs.error or hs is HomingStatus.INTERRUPTED:
                self._homing = False
        elif self._homing and not enabled:
            self._homing = False
        turning = velocity is not None and abs(float(velocity)) > 0
        if mode is not None and int(mode) == Mode.PROFILE_POSITION and enabled:
            moving = turning or not reached
        else:
            moving = turning or (self._homing and hs is not HomingStatus.COMPLETED)
        inputs = obj.get("digital_inputs")
        code = obj.get("error_code")
        alarms, sw_reg = d.alarms, d.objects.get("statusword")
        if alarms is not None and (sw_reg is None or alarms.reg != sw_reg.key) and \
                values.get(alarms.reg) is not None:  # the drive's own error register
            code = values[alarms.reg]
        st = DriveStatus(
            enabled=enabled,
            moving=moving,
            in_position=not moving and not fault and (reached or not enabled),
            homed=self._bit_says("homed", values) if "homed" not in self.tracked
            else self._homed,  # a flag the drive keeps says it, not our record, once it has one
            alarm=fault,
            alarm_code=int(code) if fault and code is not None else (0 if fault else None),
            alarm_text=self.alarm_text(int(code)) if fault and code else "",
            limit_positive=bool(inputs is not None and int(inputs) & DigitalInput.POSITIVE_LIMIT),
            limit_negative=bool(inputs is not None and int(inputs) & DigitalInput.NEGATIVE_LIMIT),
            homing=self._homing,
            homing_error=hs is not None and hs.error,
            position=None if obj.get("position_actual_value") is None else
            int(obj["position_actual_value"]),
            velocity_rpm=None if velocity is None else float(velocity),
            requested_at=requested_at or 0.0,
            raw={**self._polled_raw(values, raw_words),
                 "statusword": sw, "state": list(State).index(state) if state else -1,
                 **({"mode": int(mode)} if mode is not None else {}),
                 **({"error_code": int(code)} if code is not None else {}),
                 **({"inputs": int(inputs)} if inputs is not None else {})},
            timestamp=monotonic(),
        )
        return self._overrides(st, values)

    def _polled_raw(self, values: Mapping[str, Any],
                    raw_words: Mapping[str, list[int]] | None) -> dict[str, int]:
        """``[status] raw``'s entries where the description gives them, else each polled
        register's own value (its words before scale and unit), as the command engine's."""
        s = self.description.status
        if s.raw:
            return raw_values(s.raw, self._scope(None, values))
        return polled_raw(self.description, values, raw_words)

    def _bit_says(self, meaning: str, values: Mapping[str, Any]) -> bool:
        """Whether a bit of a polled register that ``means`` it is set: a drive's own flag
        beside the state machine (the Lexium 32's ref_ok, statusword bit 15: homed, also
        after a reconnect or a homing the engine did not run)."""
        for reg in self.description.regs.values():
            v = values.get(reg.key)
            if v is None or isinstance(v, Unread):
                continue
            if any(b.means == meaning and int(v) & b.mask for b in reg.d.bits.values()):
                return True
        return False

    def _overrides(self, st: DriveStatus, values: Mapping[str, Any]) -> DriveStatus:
        s = self.description.status
        fields = {k: getattr(s, k) for k in ("enabled", "moving", "in_position", "homed",
                                              "homing", "homing_error", "alarm",
                                              "limit_positive",
                                              "limit_negative")
                  if getattr(s, k) is not None}
        if not fields:
            return st
        scope = self._scope(None, values)
        scope["words"] = Attrs("words", {})
        changed = {k: bool(e(scope)) for k, e in fields.items()}
        return DriveStatus(**{**st.__dict__, **changed})

    # -- procedures ------------------------------------------------------------------------

    async def enable(self) -> None:
        """Shutdown, switch on, enable operation, as the state machine needs (or the
        description's own ``enable``); a target velocity left in the drive is zeroed
        first and Operation enabled is reached with halt set, so enabling starts nothing."""
        if self._described("enable"):
            await super().enable()
            return
        state, _ = await self._state()
        if state is not State.OPERATION_ENABLED:
            await self._zero_target_velocity(Priority.COMMAND)
        await self.goto(State.OPERATION_ENABLED)

    async def _zero_target_velocity(self, priority: Priority) -> None:
        """Target velocity (60FFh) 0, where mapped: in profile velocity the drive runs at
        it whenever it is in Operation enabled with halt clear (the mode has no start bit,
        CiA 402-2 profile velocity mode), so none is left for an enable or a mode change
        to start."""
        if "target_velocity" in self.description.objects:
            await self._write_objects([("target_velocity", 0)], priority=priority)
            self._velocity_set = False

    async def _after_stop(self) -> None:
        """After the stop of a speed run (on the wire already): target velocity 0. The
        stop has done its work if this write fails; it is logged and tried again at the
        next stop, and enable zeroes it anyway."""
        if not self._velocity_set:
            return
        try:
            await self._zero_target_velocity(Priority.EMERGENCY)
        except TransactionError as exc:
            log.warning("%s: the stop went out, but target velocity (60FFh) was not zeroed "
                        "after it: %s", self.family, exc)

    async def disable(self) -> None:
        """Shutdown: Ready to switch on, the motor released (or the description's own)."""
        if self._described("disable"):
            await super().disable()
            return
        await self.goto(State.READY_TO_SWITCH_ON)

    def check_supported(self, procedure: str) -> None:
        """The engine's procedures exist wherever the objects they need are mapped."""
        if self._described(procedure):
            super().check_supported(procedure)
            return
        needs = {
            "enable": ("controlword",), "disable": ("controlword",),
            "move_absolute": ("modes_of_operation", "target_position", "profile_velocity"),
            "move_relative": ("modes_of_operation", "target_position", "profile_velocity"),
            "speed_run": ("modes_of_operation", "target_velocity"),
            "stop": ("controlword",), "emergency_stop": ("controlword",),
            "home": ("modes_of_operation", "homing_method"),
            "clear_alarm": ("controlword",),
        }.get(procedure)
        if needs is None:
            if procedure == "zero_position" and self._current_position_method() is not None:
                return
            super().check_supported(procedure)
            return
        for name in needs:
            self._obj(name)
        if procedure == "home" and self.description.homing is None:
            raise self.unsupported("home", "its description lists no homing method")

    async def _set_mode(self, mode: int) -> None:
        """Write the mode of operation; where the drive maps its display (6061), wait
        (bounded) until it shows the mode: a set-point sent before the drive has changed
        modes is lost."""
        await self._write_objects([("modes_of_operation", mode)])
        display = self.description.objects.get("modes_of_operation_display")
        if display is None:
            return
        try:
            with anyio.fail_after(self._timeout):
                while await self.read(display.register) != mode:  # noqa: ASYNC110
                    await anyio.sleep(0.002)  # the poll period; the drive's read decides
        except TimeoutError:
            raise StateError(f"{self.family}: the drive did not change to mode {mode} within "
                             f"{self._timeout:g} s (its mode display)") from None

    async def _enabled_or_raise(self) -> None:
        state, _ = await self._state()
        if state is not State.OPERATION_ENABLED:
            raise StateError(f"{self.family}: the drive is in {state}, not Operation "
                             f"enabled: enable it first")

    def _move_values(self, params: MoveParams) -> list[tuple[str, float]]:
        values = [("profile_velocity", abs(params.speed_rpm))]
        for name, v in (("profile_acceleration", params.accel_rps2),
                        ("profile_deceleration", params.decel_rps2)):
            if name in self.description.objects:
                values.append((name, v))
        return values

    def check_move(self, params: MoveParams, position: int = 0) -> None:
        """Range-check the profile velocity, acceleration and deceleration and the target
        position (no I/O)."""
        if self._described("move_absolute"):
            super().check_move(params, position)
            return
        self._raw("target_position", position)
        for name, v in self._move_values(params):
            raw = self._raw(name, v)
            if raw == 0:
                reg = self._obj(name).register
                raise LimitViolation(
                    f"value {v:g} for register {reg.name} (address {reg.address}) rounds to "
                    f"0: the drive would not move")

    def quantize(self, params: MoveParams) -> MoveParams:
        """What the objects' resolution makes of ``params``."""
        if self._described("move_absolute"):
            return super().quantize(params)
        out = {"profile_velocity": abs(params.speed_rpm),
               "profile_acceleration": params.accel_rps2,
               "profile_deceleration": params.decel_rps2}
        for name, v in list(out.items()):
            reg = self.description.objects.get(name)
            if reg is None:
                continue
            try:
                raw = self._raw(name, v)
            except LimitViolation:
                continue
            out[name] = abs(float(reg.codec.to_physical(raw, ppr=self.pulses_per_rev)))
        return MoveParams(out["profile_velocity"], out["profile_acceleration"],
                          out["profile_deceleration"])

    async def _prepare(self, target: int, params: MoveParams) -> None:
        self.check_move(params)
        self._raw("target_position", target)
        await self._enabled_or_raise()
        await self._set_mode(Mode.PROFILE_POSITION)
        await self._write_objects([*self._move_values(params), ("target_position", target)])

    async def _set_point(self, *, relative: bool) -> None:
        c = self.description.cia402
        hs = SetPointHandshake(_ENABLED, relative=relative,
                               immediate=bool(c and c.change_set_immediately))
        if self._last_cw is None or self._last_cw & Controlword.NEW_SET_POINT:
            # The drive takes a set-point on bit 4's rising edge: a bit 4 left high (by a
            # homing start, or unknown after a reconnect) goes low first.
            await self._controlword((self._last_cw or _ENABLED) & ~Controlword.NEW_SET_POINT)
        try:
            with anyio.fail_after(self._timeout):
                while not hs.accepted:
                    sw = await self._statusword()
                    word = hs.controlword(sw)
                    if word is not None:
                        await self._controlword(word)
                        if hs.accepted:
                            break
                        continue
                    await anyio.sleep(0.002)  # the poll period; the statusword decides
        except TimeoutError:
            raise StateError(f"{self.family}: the drive did not acknowledge the set-point "
                             f"within {self._timeout:g} s") from None

    async def move_absolute(self, position: int, params: MoveParams) -> None:
        """Profile position: objects, then the new-set-point handshake."""
        if self._described("move_absolute"):
            await super().move_absolute(position, params)
            return
        await self._prepare(position, params)
        await self._set_point(relative=False)

    async def prepare_absolute(self, position: int, params: MoveParams) -> None:
        """Mode and objects of a move: everything but the handshake."""
        if self._described("move_absolute"):
            await super().prepare_absolute(position, params)
            return
        await self._prepare(position, params)

    async def start_absolute(self) -> None:
        """The handshake of the prepared move."""
        if self._described("move_absolute"):
            await super().start_absolute()
            return
        await self._set_point(relative=False)

    async def move_relative(self, distance: int, params: MoveParams) -> None:
        """Profile position with the relative bit."""
        if self._described("move_relative"):
            await super().move_relative(distance, params)
            return
        await self._prepare(distance, params)
        await self._set_point(relative=True)

    async def speed_run(self, speed_rpm: float, accel_rps2: float, decel_rps2: float) -> None:
        """Profile velocity at ``speed_rpm`` (signed); 0 is a decelerating stop."""
        if self._described("speed_run"):
            await super().speed_run(speed_rpm, accel_rps2, decel_rps2)
            return
        values: list[tuple[str, float]] = [("target_velocity", speed_rpm)]
        for name, v in (("profile_acceleration", accel_rps2),
                        ("profile_deceleration", decel_rps2)):
            if name in self.description.objects:
                values.append((name, v))
        for name, v in values:
            self._raw(name, v)  # range-checked before anything is sent
        if round(speed_rpm, 9) == 0:
            await self.stop(decel_rps2)
            return
        await self._enabled_or_raise()
        # The target first: the mode change to profile velocity then runs at this speed,
        # never at one left from before (halt may be clear, the mode has no start bit).
        await self._write_objects(values)
        self._velocity_set = True
        await self._set_mode(Mode.PROFILE_VELOCITY)
        await self._controlword(_ENABLED)  # halt clear: run

    def check_stop(self, decel_rps2: float | None) -> None:
        """A deceleration the halt cannot take, or one beyond the profile deceleration's
        range, is refused before anything is sent."""
        if self._described("stop"):
            super().check_stop(decel_rps2)
            return
        DriveProfile.check_stop(self, decel_rps2)
        if decel_rps2 is not None:
            self._raw("profile_deceleration", decel_rps2)

    def stop_takes_decel(self) -> bool:
        """The halt takes the profile deceleration where the description maps it."""
        if self._described("stop"):
            return super().stop_takes_decel()
        return "profile_deceleration" in self.description.objects

    async def stop(self, decel_rps2: float | None = None) -> None:
        """Halt (controlword bit 8), with ``decel_rps2`` as the profile deceleration."""
        if self._described("stop"):
            await super().stop(decel_rps2)
            return
        self.check_stop(decel_rps2)
        prio = Priority.EMERGENCY
        if decel_rps2 is not None and "profile_deceleration" in self.description.objects:
            await self._write_objects([("profile_deceleration", decel_rps2)], priority=prio)
        self._homing = False
        await self._controlword(_HALTED, priority=prio, idempotent=True)
        await self._after_stop()

    async def emergency_stop(self) -> None:
        """Quick stop (or halt, as ``[cia402] emergency_stop`` says)."""
        if self._described("emergency_stop"):
            await super().emergency_stop()
            return
        c = self.description.cia402
        self._homing = False
        word = (_HALTED if c is not None and c.emergency_stop == "halt"
                else COMMAND_WORDS[Command.QUICK_STOP])
        await self._controlword(word, priority=Priority.EMERGENCY, idempotent=True)
        await self._after_stop()

    def check_homing(self, params: HomingParams) -> None:
        """The method known, its values within range, an offset only with home_offset."""
        if self._described("home"):
            super().check_homing(params)
            return
        self._homing_values(params)

    def _homing_values(self, params: HomingParams) -> list[tuple[str, float | int]]:
        """The objects a homing writes, range-checked (no I/O)."""
        _, m = self._home_method(params.method)
        number = m.cia402 if m.cia402 is not None else m.code
        values: list[tuple[str, float | int]] = [("homing_method", number)]
        for name, v in (("homing_speed_search", params.speed_rpm),
                        ("homing_speed_zero", params.creep_rpm),
                        ("homing_acceleration", params.accel_rps2),
                        ("home_offset", params.offset)):
            if name in self.description.objects:
                values.append((name, v))
        for name, v in values:
            self._raw(name, v)
        if params.offset and "home_offset" not in self.description.objects:
            raise self.unsupported(f"home with an offset of {params.offset:g} pulses",
                                   "its description maps no register to home_offset (607C)")
        return values

    async def start_homing(self, params: HomingParams) -> None:
        """Homing mode with the method's number, speeds, acceleration and offset, then the
        rising edge of controlword bit 4."""
        if self._described("home"):
            await super().start_homing(params)
            return
        values = self._homing_values(params)
        await self._enabled_or_raise()
        await self._set_mode(Mode.HOMING)
        await self._write_objects(values)
        await self._controlword(_ENABLED)
        self._homing, self._homed = True, False
        await self._controlword(_ENABLED | Controlword.HOMING_START)

    async def clear_alarm(self) -> None:
        """Fault reset: bit 7's rising edge (the drive then shows Switch on disabled)."""
        if self._described("clear_alarm"):
            await super().clear_alarm()
            return
        state, _ = await self._state()
        if state not in (State.FAULT, State.FAULT_REACTION_ACTIVE):
            return
        await self.goto(State.SWITCH_ON_DISABLED)

    def _current_position_method(self) -> str | None:
        h = self.description.homing
        if h is None:
            return None
        return next((n for n, m in h.methods.items() if m.cia402 in (35, 37)), None)

    async def zero_position(self) -> None:
        """Homing on the current position (method 35/37) with offset 0, where described."""
        if self._described("zero_position"):
            await super().zero_position()
            return
        method = self._current_position_method()
        if method is None:
            raise self.unsupported("set its position to zero",
                                   "it lists no homing method on the current position")
        await self.start_homing(HomingParams(method, offset=0))


def cia402_attrs(d: Any) -> dict[str, Any]:
    """The class attributes of a CiA 402 description's profile: its status poll."""
    names = [n for n in STATUS_OBJECTS if n in d.objects]
    if "modes_of_operation_display" not in d.objects and "modes_of_operation" in d.objects:
        names.append("modes_of_operation")
    regs = [(d.objects[n], None) for n in names]
    alarms = d.alarms
    if alarms is not None and all(r.key != alarms.reg for r, _ in regs):
        regs.append((d.regs[alarms.reg], None))  # the drive's own error register (Kinco's
        # Error_State): the alarm code where it is not the CiA 402 error code
    link = d.link
    return {"_status_plan": plan_reads(regs, max_read=link.max_read, max_hole=link.max_hole),
            "_status_objects": tuple(names)}
