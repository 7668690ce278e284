"""The device control state machine (CiA 402-2: commands, quick stop, faults), the
controlword's mode bits (new set-point, halt), and the device's time: what happened
up to now, in order.
"""

from __future__ import annotations

from drivebus.drives.cia402 import Command, Controlword, Mode, State, decode_command, transition
from drivebus.sim.cia402_device.base import DeviceBase
from drivebus.sim.cia402_device.state import _Action, _Events, _Profile


class StateMachine(DeviceBase):
    """The state machine, the mode bits and the events up to now."""

    def _running(self, mode: Mode) -> bool:
        return self.state is State.OPERATION_ENABLED and self.mode == mode

    def _controlword(self, word: int, old: int, now: float) -> None:
        command = decode_command(word, old)
        if command is not None:
            self._command(command, now)
        if self.state is State.OPERATION_ENABLED:
            self._mode_bits(word, old, now)

    def _command(self, command: Command, now: float) -> None:
        before = self.state
        t = transition(before, command)
        if before is State.READY_TO_SWITCH_ON and command is Command.ENABLE_OPERATION:
            if self.setup.switch_on_enables:
                self._enter_enabled(now)
            return
        if t is None or (t.number == 16 and self.values["quick_stop_option_code"] < 5):
            return
        if t.number == 11:
            self._quick_stop(now)
            return
        self.state = t.target
        if t.target is State.OPERATION_ENABLED:
            self._enter_enabled(now)
        elif before is State.OPERATION_ENABLED:
            ramp = self._rate("profile_deceleration") if t.number == 5 else None
            self._end_motion(now, ramp)
        elif t.number == 15:
            self.error_code = 0

    def _enter_enabled(self, now: float) -> None:
        """Operation enabled: the axis holds where it is; no set-point in progress."""
        self.state = State.OPERATION_ENABLED
        self._profile = _Profile()
        self._halted = bool(self.values["controlword"] & Controlword.HALT)
        if self._running(Mode.PROFILE_VELOCITY) and not self._halted:
            self._velocity(now)

    def _quick_stop(self, now: float) -> None:
        option = self.values["quick_stop_option_code"]
        if option in (1, 5):
            ramp = self._rate("profile_deceleration")
        elif option in (2, 6):
            ramp = self._rate("quick_stop_deceleration")
        else:
            ramp = None
        self._end_motion(now, ramp)
        self.state = State.QUICK_STOP_ACTIVE

    def _end_motion(self, now: float, ramp: float | None) -> None:
        """Stop whatever runs (on ``ramp``, None: at once) and forget its set-points."""
        self._stop(now, ramp)
        if self._homing is not None:
            self._homing = None
            self._homing_result = "interrupted"
        self._drop_set_points()

    def _drop_set_points(self) -> None:
        """Forget the waiting set-point (acknowledge drops unless bit 4 is still held); the
        motion in progress ended short."""
        self._profile.pending = None
        self._profile.ended_short = True
        self._profile.halted = None
        if not self.values["controlword"] & Controlword.NEW_SET_POINT:
            self._profile.acknowledge = False
        self._watch_from = None

    def _set_mode(self, value: int, now: float) -> None:
        if value == self.mode:
            return
        if self.kin.moving(now) or self._homing is not None:
            self._end_motion(now, self._rate("profile_deceleration"))
        self.mode = value
        self._profile = _Profile()
        if self._running(Mode.PROFILE_VELOCITY) and not self._halted:
            self._velocity(now)

    def _mode_bits(self, word: int, old: int, now: float) -> None:
        halt = bool(word & Controlword.HALT)
        rising = word & Controlword.NEW_SET_POINT and not old & Controlword.NEW_SET_POINT
        falling = old & Controlword.NEW_SET_POINT and not word & Controlword.NEW_SET_POINT
        if halt and not self._halted:
            self._halt(now)
        self._halted = halt
        if self.mode == Mode.PROFILE_POSITION:
            if rising and not halt:
                self._new_set_point(word, now)
            elif not halt and old & Controlword.HALT and self._profile.halted is not None:
                self._continue(now)  # "positioning shall be executed or continued"
            elif falling and self._profile.pending is None:
                self._profile.acknowledge = False
        elif self.mode == Mode.PROFILE_VELOCITY:
            if not halt and old & Controlword.HALT:
                self._velocity(now)
        elif self.mode == Mode.HOMING:
            if rising and not halt:
                self._start_homing(now)
            elif falling and self._homing is not None:
                self._end_motion(now, self._rate("homing_acceleration"))

    def _halt(self, now: float) -> None:
        prof = self._profile
        interrupted = (prof.target if self.mode == Mode.PROFILE_POSITION and prof.target
                       is not None and abs(self.kin.position(now) - prof.target) >= 0.5
                       else None)
        self._halt_motion(now)
        prof.halted = interrupted

    def _halt_motion(self, now: float) -> None:
        option = self.values["halt_option_code"]
        if self.mode == Mode.HOMING:
            ramp = self._rate("homing_acceleration")
        elif option == 1:
            ramp = self._rate("profile_deceleration")
        elif option == 2:
            ramp = self._rate("quick_stop_deceleration")
        else:
            ramp = None
        self._end_motion(now, ramp)

    def advance(self, now: float) -> None:
        """Run what happened up to ``now``: the end of booting, of a quick stop or fault
        reaction, a waiting set-point's start, limit switches met, homing legs."""
        for _ in range(64):
            event = self._next_event(now)
            if event is None:
                return
            t, action = event
            action(t)
        raise RuntimeError("the simulated CiA 402 device did not settle (an event loop)")

    def _next_event(self, now: float) -> tuple[float, _Action] | None:
        if not self.powered:
            return None
        events = _Events()
        end = self.kin.end_time()
        stopped = end if end <= now else None
        if self.state is State.NOT_READY_TO_SWITCH_ON and self._boot_until <= now:
            events.add(self._boot_until, self._to(State.SWITCH_ON_DISABLED))
        elif self.state is State.FAULT_REACTION_ACTIVE:
            events.add(stopped, self._to(State.FAULT))  # transition 14
        elif (self.state is State.QUICK_STOP_ACTIVE
              and self.values["quick_stop_option_code"] in range(0, 5)):
            events.add(stopped, self._to(State.SWITCH_ON_DISABLED))  # transition 12
        elif self.state is State.OPERATION_ENABLED:
            if self._homing is not None:
                homing = self._homing_event(now)
                if homing is not None:
                    events.add(*homing)
            else:
                events.add(self._limit_hit(now), self._stop_at_limit)
            if self._profile.pending is not None and self.mode == Mode.PROFILE_POSITION:
                events.add(stopped, self._take_pending)
            if self._pv_deferred:
                events.add(stopped, self._resume_velocity)
        return events.first()

    def _resume_velocity(self, t: float) -> None:
        self._pv_deferred = False
        if self._running(Mode.PROFILE_VELOCITY) and not self._halted:
            self._velocity(t)

    def _to(self, state: State) -> _Action:
        """An automatic transition to ``state``."""
        def action(_t: float) -> None:
            self.state = state
        return action

    def _take_pending(self, t: float) -> None:
        prof = self._profile
        assert prof.pending is not None
        point, prof.pending = prof.pending, None
        if not self.values["controlword"] & Controlword.NEW_SET_POINT:
            prof.acknowledge = False
        self._start_point(point, t)
