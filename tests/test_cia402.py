"""CiA 402 logic (drives/cia402.py) and the simulated CiA 402 device (sim/cia402_device.py)."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivebus.drives.cia402 import (
    COMMAND_WORDS,
    HOMING_METHODS,
    MAX_STEPS,
    OBJECTS,
    Command,
    Controlword,
    DigitalInput,
    HomeSignal,
    HomeSwitch,
    HomingMethod,
    HomingStatus,
    Mode,
    SetPointHandshake,
    State,
    Statusword,
    StatuswordError,
    decode_command,
    decode_state,
    homing_method,
    homing_status,
    next_step,
    transition,
)
from drivebus.errors import ArgumentError
from drivebus.sim.cia402_device import Cia402Device, Cia402Setup
from drivebus.sim.registers import ExceptionCodes, SlaveException

# -- statusword decoding ------------------------------------------------------------------------

# (state, statusword as drives show it): the spec's bit patterns plus voltage enabled
# (bit 4), remote (bit 9), target reached (bit 10) as real drives set them.
TYPICAL = [
    (State.NOT_READY_TO_SWITCH_ON, 0x0000),
    (State.NOT_READY_TO_SWITCH_ON, 0x0020),
    (State.SWITCH_ON_DISABLED, 0x0040),
    (State.SWITCH_ON_DISABLED, 0x0250),
    (State.SWITCH_ON_DISABLED, 0x0270),
    (State.READY_TO_SWITCH_ON, 0x0021),
    (State.READY_TO_SWITCH_ON, 0x0231),
    (State.SWITCHED_ON, 0x0023),
    (State.SWITCHED_ON, 0x0233),
    (State.OPERATION_ENABLED, 0x0027),
    (State.OPERATION_ENABLED, 0x0637),
    (State.OPERATION_ENABLED, 0x1637),
    (State.QUICK_STOP_ACTIVE, 0x0007),
    (State.QUICK_STOP_ACTIVE, 0x0217),
    (State.FAULT_REACTION_ACTIVE, 0x000F),
    (State.FAULT_REACTION_ACTIVE, 0x021F),
    (State.FAULT, 0x0008),
    (State.FAULT, 0x0218),
    (State.FAULT, 0x0238),
]


@pytest.mark.parametrize(("state", "word"), TYPICAL)
def test_every_state_decodes_from_its_statusword(state: State, word: int) -> None:
    assert decode_state(word) is state


def test_the_state_masks_partition_the_statusword() -> None:
    """Every 16-bit word matches at most one state; those that match none are refused
    with a typed error naming the word."""
    undefined = 0
    for word in range(1 << 16):
        matching = [s for s in State if s.matches(word)]
        assert len(matching) <= 1, (hex(word), matching)
        if not matching:
            undefined += 1
            with pytest.raises(StatuswordError, match=f"0x{word:04X}"):
                decode_state(word)
    assert 0 < undefined < 1 << 16


@given(st.sampled_from(list(State)), st.integers(0, 0xFFFF))
def test_noise_in_other_bits_never_changes_the_state(state: State, noise: int) -> None:
    irrelevant = 0xFFFF & ~state.mask  # bits 4, 7-15, and bit 5 where the mask is 0x4F
    assert decode_state(state.bits | (noise & irrelevant)) is state


def test_state_bits_and_power_stage() -> None:
    assert {s for s in State if s.drive_function_enabled} == {
        State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE}
    assert str(State.SWITCH_ON_DISABLED) == "Switch on disabled"


# -- controlword commands -----------------------------------------------------------------------


def test_command_words_are_the_profiles() -> None:
    assert COMMAND_WORDS[Command.SHUTDOWN] == 0x06
    assert COMMAND_WORDS[Command.SWITCH_ON] == 0x07
    assert COMMAND_WORDS[Command.ENABLE_OPERATION] == 0x0F
    assert COMMAND_WORDS[Command.DISABLE_VOLTAGE] == 0x00
    assert COMMAND_WORDS[Command.QUICK_STOP] == 0x02
    assert COMMAND_WORDS[Command.DISABLE_OPERATION] == 0x07
    assert COMMAND_WORDS[Command.FAULT_RESET] == 0x80
    for command, word in COMMAND_WORDS.items():
        if command is Command.FAULT_RESET:
            assert decode_command(word, 0) is command
        else:
            expect = Command.SWITCH_ON if command is Command.DISABLE_OPERATION else command
            assert decode_command(word) is expect


@given(st.integers(0, 0xFFFF), st.integers(0, 0xFFFF))
def test_a_command_is_made_of_bits_0_to_3_and_7_only(word: int, noise: int) -> None:
    mode_bits = noise & ~0x8F & 0xFFFF
    assert decode_command(word | mode_bits, 0) is decode_command(word & 0x8F, 0)


def test_fault_reset_is_the_rising_edge_of_bit_7() -> None:
    assert decode_command(0x80, previous=0x00) is Command.FAULT_RESET
    assert decode_command(0x80, previous=0x0F) is Command.FAULT_RESET
    assert decode_command(0x80, previous=0x80) is None  # held: no edge, no command
    assert decode_command(0x8F, previous=0x80) is None
    assert decode_command(0x80, previous=None) is None  # unknown before: no edge
    # The table's x (don't care) bits: quick stop with bit 0 and 3 anything.
    assert decode_command(0x0B) is Command.QUICK_STOP
    assert decode_command(0x0D) is Command.DISABLE_VOLTAGE
    assert decode_command(0x0E) is Command.SHUTDOWN


# The transitions of CiA 402-2's state diagram, written out from the spec's table.
SPEC = {
    (State.SWITCH_ON_DISABLED, Command.SHUTDOWN): (2, State.READY_TO_SWITCH_ON),
    (State.READY_TO_SWITCH_ON, Command.SWITCH_ON): (3, State.SWITCHED_ON),
    (State.SWITCHED_ON, Command.ENABLE_OPERATION): (4, State.OPERATION_ENABLED),
    (State.OPERATION_ENABLED, Command.SWITCH_ON): (5, State.SWITCHED_ON),
    (State.SWITCHED_ON, Command.SHUTDOWN): (6, State.READY_TO_SWITCH_ON),
    (State.READY_TO_SWITCH_ON, Command.DISABLE_VOLTAGE): (7, State.SWITCH_ON_DISABLED),
    (State.READY_TO_SWITCH_ON, Command.QUICK_STOP): (7, State.SWITCH_ON_DISABLED),
    (State.OPERATION_ENABLED, Command.SHUTDOWN): (8, State.READY_TO_SWITCH_ON),
    (State.OPERATION_ENABLED, Command.DISABLE_VOLTAGE): (9, State.SWITCH_ON_DISABLED),
    (State.SWITCHED_ON, Command.DISABLE_VOLTAGE): (10, State.SWITCH_ON_DISABLED),
    (State.SWITCHED_ON, Command.QUICK_STOP): (10, State.SWITCH_ON_DISABLED),
    (State.OPERATION_ENABLED, Command.QUICK_STOP): (11, State.QUICK_STOP_ACTIVE),
    (State.QUICK_STOP_ACTIVE, Command.DISABLE_VOLTAGE): (12, State.SWITCH_ON_DISABLED),
    (State.FAULT, Command.FAULT_RESET): (15, State.SWITCH_ON_DISABLED),
    (State.QUICK_STOP_ACTIVE, Command.ENABLE_OPERATION): (16, State.OPERATION_ENABLED),
}


@pytest.mark.parametrize("state", list(State))
@pytest.mark.parametrize("command", list(Command))
def test_transitions_are_the_specs(state: State, command: Command) -> None:
    t = transition(state, command)
    same_bits = Command.SWITCH_ON if command is Command.DISABLE_OPERATION else command
    expected = SPEC.get((state, same_bits))
    assert (None if t is None else (t.number, t.target)) == expected


# -- the way to a state -----------------------------------------------------------------------

GOALS = [State.OPERATION_ENABLED, State.SWITCHED_ON, State.READY_TO_SWITCH_ON,
         State.SWITCH_ON_DISABLED]
AUTOMATIC = {State.NOT_READY_TO_SWITCH_ON: State.SWITCH_ON_DISABLED,
             State.FAULT_REACTION_ACTIVE: State.FAULT}


def _walk(start: State, goal: State, last: int | None) -> list[int | None]:
    """Follow ``next_step`` on a drive that obeys the spec's table (and moves on by itself
    where the spec says so); the controlwords sent."""
    state, sent = start, []
    previous = 0 if last is None else last
    for _ in range(MAX_STEPS + 1):
        step = next_step(state, goal, last)
        if step is None:
            return sent
        sent.append(step.controlword)
        if step.controlword is None:
            state = AUTOMATIC[state]
        else:
            command = decode_command(step.controlword, previous)
            t = transition(state, command) if command else None
            assert t is not None or step.expect is state, (state, step)
            state = t.target if t else state
            previous = last = step.controlword
        assert state is step.expect
    raise AssertionError(f"{start} -> {goal} took more than {MAX_STEPS} steps: {sent}")


@pytest.mark.parametrize("start", list(State))
@pytest.mark.parametrize("goal", GOALS)
@pytest.mark.parametrize("last", [None, 0x00, 0x80, 0x0F, 0x8F])
def test_next_step_reaches_every_goal_from_every_state(start: State, goal: State,
                                                       last: int | None) -> None:
    sent = _walk(start, goal, last)
    assert len(sent) <= MAX_STEPS
    assert Command.QUICK_STOP not in {decode_command(w) for w in sent if w is not None}


def test_the_enable_sequence_is_shutdown_switch_on_enable_operation() -> None:
    assert _walk(State.SWITCH_ON_DISABLED, State.OPERATION_ENABLED, 0) == [0x06, 0x07, 0x0F]
    assert _walk(State.NOT_READY_TO_SWITCH_ON, State.OPERATION_ENABLED, 0) == [
        None, 0x06, 0x07, 0x0F]
    # From a fault: bit 7 down (if it may be up), its rising edge, then the enable sequence.
    assert _walk(State.FAULT, State.OPERATION_ENABLED, 0x0F) == [0x80, 0x06, 0x07, 0x0F]
    assert _walk(State.FAULT, State.OPERATION_ENABLED, None) == [0x00, 0x80, 0x06, 0x07, 0x0F]
    assert _walk(State.FAULT_REACTION_ACTIVE, State.OPERATION_ENABLED, 0x80) == [
        None, 0x00, 0x80, 0x06, 0x07, 0x0F]
    # Quick stop active goes through Switch on disabled (transition 16 is optional).
    assert _walk(State.QUICK_STOP_ACTIVE, State.OPERATION_ENABLED, 0x02) == [
        0x00, 0x06, 0x07, 0x0F]
    assert _walk(State.OPERATION_ENABLED, State.SWITCH_ON_DISABLED, 0x0F) == [0x00]
    assert _walk(State.OPERATION_ENABLED, State.SWITCHED_ON, 0x0F) == [0x07]


def test_a_state_the_master_cannot_command_is_no_goal() -> None:
    for goal in (State.FAULT, State.QUICK_STOP_ACTIVE, State.NOT_READY_TO_SWITCH_ON,
                 State.FAULT_REACTION_ACTIVE):
        with pytest.raises(ArgumentError, match="cannot be commanded"):
            next_step(State.OPERATION_ENABLED, goal)


# -- the new-set-point handshake ------------------------------------------------------------------

ACK = Statusword.SET_POINT_ACKNOWLEDGE
ENABLED = State.OPERATION_ENABLED.bits


def test_handshake_raises_bit_4_then_clears_it_on_acknowledge() -> None:
    hs = SetPointHandshake(relative=True, immediate=True)
    assert hs.request == 0x0F | 0x10 | 0x20 | 0x40
    assert hs.controlword(ENABLED) == hs.request
    assert hs.controlword(ENABLED) is None  # no ack yet: wait
    assert not hs.accepted
    assert hs.controlword(ENABLED | ACK) == 0x0F | 0x20 | 0x40
    assert hs.accepted
    assert hs.controlword(ENABLED) is None


def test_handshake_waits_while_the_drive_still_acknowledges_the_last_set_point() -> None:
    hs = SetPointHandshake(0x0F | Controlword.HALT | Controlword.NEW_SET_POINT)
    assert hs.base == 0x010F  # the caller's new set-point bit never leaks into the base
    assert hs.controlword(ENABLED | ACK) is None
    assert not hs.requested
    assert hs.controlword(ENABLED) == 0x011F
    assert hs.controlword(ENABLED | ACK) == 0x010F


# -- modes, homing ------------------------------------------------------------------------------


def test_modes() -> None:
    assert (Mode.PROFILE_POSITION, Mode.PROFILE_VELOCITY, Mode.HOMING) == (1, 3, 6)
    assert Mode.PROFILE_POSITION.supported_bit == 0x01
    assert Mode.HOMING.supported_bit == 0x20
    assert Mode.NO_MODE.supported_bit == 0


@pytest.mark.parametrize(("word", "status"), [
    (0x0000, HomingStatus.IN_PROGRESS),
    (0x0400, HomingStatus.INTERRUPTED),
    (0x1000, HomingStatus.ATTAINED),
    (0x1400, HomingStatus.COMPLETED),
    (0x2000, HomingStatus.ERROR_MOVING),
    (0x2400, HomingStatus.ERROR_STOPPED),
    (0x3000, HomingStatus.RESERVED),
    (0x3400, HomingStatus.RESERVED),
])
def test_homing_status_bits(word: int, status: HomingStatus) -> None:
    assert homing_status(word | 0x0237) is status
    assert status.error == bool(word & 0x2000)


def test_homing_methods_say_what_they_home_on_and_which_limits_they_meet() -> None:
    assert sorted(HOMING_METHODS) == [*range(1, 15), *range(17, 31), 33, 34, 35, 37]
    neg, pos = HomeSignal.NEGATIVE_LIMIT, HomeSignal.POSITIVE_LIMIT
    m1, m17 = homing_method(1), homing_method(17)
    assert (m1.signal, m1.index_pulse, m1.initial_direction, m1.final_direction) == (
        neg, True, -1, +1)
    assert (m17.signal, m17.index_pulse, m17.final_direction) == (neg, False, +1)
    assert homing_method(18).limit_switches == {pos}
    assert homing_method(19).limit_switches == frozenset()
    assert homing_method(19).initial_direction == 0  # the switch's state decides
    assert homing_method(7).limit_switches == {pos}  # reverses on it
    assert homing_method(11).limit_switches == {neg}
    assert homing_method(34).signal is HomeSignal.INDEX_PULSE
    assert homing_method(34).final_direction == +1
    assert not homing_method(35).moves and not homing_method(37).moves
    for n in range(1, 15):  # 17..30 are 1..14 without the index pulse
        a, b = homing_method(n), homing_method(n + 16)
        assert (a.signal, a.final_direction, a.initial_direction, a.home_switch,
                a.reversal_limit) == (b.signal, b.final_direction, b.initial_direction,
                                      b.home_switch, b.reversal_limit)
        assert a.index_pulse and not b.index_pulse
    for n in (0, 15, 16, 31, 32, 36, -1, 38):
        with pytest.raises(ArgumentError, match=f"homing method {n} is not"):
            homing_method(n)


def test_objects_carry_index_type_and_access() -> None:
    cw, pos = OBJECTS["controlword"], OBJECTS["position_actual_value"]
    assert (cw.index, cw.subindex, cw.bits, cw.signed, cw.writable) == (0x6040, 0, 16, False, True)
    assert (pos.minimum, pos.maximum, pos.writable) == (-(2**31), 2**31 - 1, False)
    assert OBJECTS["homing_speed_zero"].subindex == 2
    assert OBJECTS["modes_of_operation"].minimum == -128


# == the simulated device =========================================================================

LIMITS = {"limit_negative": -50_000.0, "limit_positive": 50_000.0}
SETUP = Cia402Setup(**LIMITS, home_switch=10_000.0, increments_per_rev=10_000,
                    index_offset=2_500.0)


def device(setup: Cia402Setup = SETUP, **values: int) -> Cia402Device:
    """A device at t = 0, with ``values`` written."""
    d = Cia402Device(setup, now=0.0)
    for name, value in values.items():
        d.write(name, value, 0.0)
    return d


def enable(d: Cia402Device, t: float = 0.0, goal: State = State.OPERATION_ENABLED) -> float:
    """Take ``d`` to ``goal`` by ``next_step`` (waiting where it says); the time then."""
    last = d.read("controlword", t)
    for _ in range(MAX_STEPS + 1):
        step = next_step(d.state_at(t), goal, last)
        if step is None:
            return t
        if step.controlword is None:
            waited = t
            while d.state_at(t) is not step.expect:  # the drive moves on by itself
                t += 0.01
                assert t - waited < 5.0, f"stuck in {d.state_at(t)}"
        else:
            d.write("controlword", step.controlword, t)
            last = step.controlword
        assert d.state_at(t) is step.expect
    raise AssertionError(f"{goal} not reached in {MAX_STEPS} steps: {d.state_at(t)}")


def handshake(d: Cia402Device, t: float, target: int, **bits: bool) -> float:
    """Hand over target position ``target`` with the new-set-point handshake; the time the
    drive took it (polls 1 ms apart, for up to 60 s: a set-point may have to wait)."""
    d.write("target_position", target, t)
    hs = SetPointHandshake(d.read("controlword", t), **bits)
    for _ in range(60_000):
        word = hs.controlword(d.statusword(t))
        if word is not None:
            d.write("controlword", word, t)
        if hs.accepted:
            return t
        t += 0.001
    raise AssertionError("the set-point handshake did not complete")


def pp(d: Cia402Device, t: float = 0.0) -> float:
    t = enable(d, t)
    d.write("modes_of_operation", Mode.PROFILE_POSITION, t)
    return t


def settle(d: Cia402Device, t: float, limit: float = 60.0) -> float:
    """The time (10 ms steps) at which the axis stands still."""
    while d.is_moving(t):
        t += 0.01
        assert t < limit, "the axis never came to rest"
    return t


# -- state machine -----------------------------------------------------------------------------


def test_power_up_goes_from_not_ready_to_switch_on_disabled_after_booting() -> None:
    d = Cia402Device(replace(SETUP, boot_time=0.2), now=1.0)
    assert d.state_at(1.1) is State.NOT_READY_TO_SWITCH_ON
    d.write("controlword", 0x06, 1.1)  # ignored while booting
    assert decode_state(d.statusword(1.19)) is State.NOT_READY_TO_SWITCH_ON
    assert d.state_at(1.2) is State.SWITCH_ON_DISABLED
    assert d.statusword(1.2) & Statusword.REMOTE


def _bring_to(state: State) -> tuple[Cia402Device, float]:
    """A device in ``state`` (motor at rest), and the time."""
    d = device(replace(SETUP, boot_time=0.5), quick_stop_option_code=6)
    if state is State.NOT_READY_TO_SWITCH_ON:
        return d, 0.1
    t = 0.5
    if state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
        t = enable(d, t)
        d.write("modes_of_operation", Mode.PROFILE_VELOCITY, t)
        d.write("target_velocity", 20_000, t)
        t += 1.0
        d.write("quick_stop_deceleration", 20_000, t)
        d.raise_fault(0x2310, t)
        return d, (t + 0.1 if state is State.FAULT_REACTION_ACTIVE else t + 2.0)
    if state is State.QUICK_STOP_ACTIVE:
        t = enable(d, t)
        d.write("controlword", 0x02, t)
        return d, t
    return d, enable(d, t, state)


@pytest.mark.parametrize("start", list(State))
def test_next_step_enables_the_device_from_every_state(start: State) -> None:
    d, t = _bring_to(start)
    assert d.state_at(t) is start
    t = enable(d, t)
    assert d.state_at(t) is State.OPERATION_ENABLED
    assert d.read("error_code", t) == 0
    t = enable(d, t, State.SWITCH_ON_DISABLED)
    assert d.state_at(t) is State.SWITCH_ON_DISABLED


class _Model:
    """The spec's state machine on its own, to check the device against."""

    def __init__(self) -> None:
        self.state, self.word = State.SWITCH_ON_DISABLED, 0

    def send(self, word: int, quick_stop_option: int) -> None:
        command = decode_command(word, self.word)
        self.word = word
        t = transition(self.state, command) if command else None
        if t is None or (t.number == 16 and quick_stop_option < 5):
            return
        self.state = t.target
        if t.number == 11 and quick_stop_option < 5:
            self.state = State.SWITCH_ON_DISABLED  # stops at once here, then transition 12


@given(st.lists(st.sampled_from([0x00, 0x02, 0x06, 0x07, 0x0F, 0x80, 0x86, 0x1F, 0x10F, 0x0B]),
                max_size=30),
       st.sampled_from([0, 2, 6, 7]))
def test_the_device_follows_the_state_machine_on_any_controlwords(words: list[int],
                                                                  option: int) -> None:
    d = device(quick_stop_option_code=option, quick_stop_deceleration=0)
    model = _Model()
    for i, word in enumerate(words):
        t = 0.01 * (i + 1)
        d.write("controlword", word, t)
        model.send(word, option)
        assert d.state_at(t) is model.state, (words[: i + 1], option)
        assert decode_state(d.statusword(t)) is model.state
        assert not d.is_moving(t)  # no mode, no set-point: the motor never turns


def test_enable_operation_in_ready_to_switch_on_only_where_the_drive_does_both() -> None:
    d = device()
    d.write("controlword", 0x06, 0.0)
    d.write("controlword", 0x0F, 0.0)
    assert d.state_at(0.0) is State.READY_TO_SWITCH_ON
    d = device(replace(SETUP, switch_on_enables=True))
    d.write("controlword", 0x06, 0.0)
    d.write("controlword", 0x0F, 0.0)
    assert d.state_at(0.0) is State.OPERATION_ENABLED


# -- profile position ----------------------------------------------------------------------------


def test_pp_move_with_the_handshake_reaches_its_target() -> None:
    d = device(profile_velocity=10_000, profile_acceleration=50_000, profile_deceleration=50_000)
    t = pp(d)
    assert d.read("modes_of_operation_display", t) == Mode.PROFILE_POSITION
    assert d.statusword(t) & Statusword.TARGET_REACHED  # nothing to do yet
    t = handshake(d, t, 30_000)
    word = d.statusword(t)
    assert not word & Statusword.SET_POINT_ACKNOWLEDGE  # bit 4 back to 0: ready for the next
    assert not word & Statusword.TARGET_REACHED
    mid = t + 1.0
    assert 0 < d.read("position_actual_value", mid) < 30_000
    assert d.read("velocity_actual_value", mid) == 10_000
    done = settle(d, t)
    assert d.read("position_actual_value", done) == 30_000
    assert d.statusword(done) & Statusword.TARGET_REACHED
    assert 3.2 < done < 3.3  # 3 s at 10000/s plus one 0.2 s ramp


def test_a_second_set_point_waits_for_the_first_then_runs() -> None:
    d = device()
    t = pp(d)
    t = handshake(d, t, 20_000)
    t = handshake(d, t + 0.5, 5_000)
    assert d.statusword(t) & Statusword.SET_POINT_ACKNOWLEDGE  # the waiting slot is taken
    hs = SetPointHandshake(d.read("controlword", t))
    assert hs.controlword(d.statusword(t)) is None  # a third must wait
    positions = [d.read("position_actual_value", t + 0.01 * i) for i in range(600)]
    assert max(positions) == 20_000  # the first target was reached, then the second
    assert positions[-1] == 5_000
    assert not d.statusword(t + 6) & Statusword.SET_POINT_ACKNOWLEDGE


def test_change_set_immediately_replaces_the_motion_at_once() -> None:
    d = device()
    t = pp(d)
    t = handshake(d, t, 40_000)
    t = handshake(d, t + 1.0, 5_000, immediate=True)
    positions = [d.read("position_actual_value", t + 0.01 * i) for i in range(500)]
    assert max(positions) < 12_000  # it never went on toward 40000
    assert positions[-1] == 5_000


def test_relative_targets_add_to_the_last_target_or_to_where_a_halt_left_the_axis() -> None:
    d = device()
    t = pp(d)
    t = handshake(d, t, 5_000, relative=True)
    t = handshake(d, t + 0.01, 5_000, relative=True)  # queued: from the first's target
    t = settle(d, t)
    assert d.read("position_actual_value", t) == 10_000
    t = handshake(d, t, 20_000, relative=True)
    d.write("controlword", 0x0F | Controlword.HALT | Controlword.RELATIVE, t + 0.5)
    t = settle(d, t + 0.5)
    stopped = d.read("position_actual_value", t)
    assert 10_000 < stopped < 30_000
    assert d.statusword(t) & Statusword.TARGET_REACHED  # halted: at rest counts as reached
    # halt off with a new set-point in the same controlword: it replaces the interrupted
    # one, relative to where the halt left the axis
    d.write("target_position", 1_000, t)
    d.write("controlword", 0x0F | Controlword.NEW_SET_POINT | Controlword.RELATIVE, t)
    assert d.read("position_actual_value", settle(d, t)) == stopped + 1_000


def test_halt_cleared_alone_continues_the_interrupted_positioning() -> None:
    """CiA 402-2, profile position, controlword bit 8: "0: positioning shall be executed or
    continued". Clearing halt without a new set-point takes the interrupted positioning on
    to its target (before: the twin dropped it, more lenient than the drives, so an engine
    that cleared halt after a stop would not have been caught). A mode change, a quick
    stop or a limit switch drops it; a new set-point replaces it."""
    d = device()
    t = handshake(d, pp(d), 30_000)
    d.write("controlword", 0x0F | Controlword.HALT, t + 0.5)
    t = settle(d, t + 0.5)
    stopped = d.read("position_actual_value", t)
    assert 0 < stopped < 30_000
    d.write("controlword", 0x0F, t)  # halt off: the positioning goes on
    assert d.is_moving(t + 0.1)
    assert d.read("position_actual_value", settle(d, t + 0.1)) == 30_000
    t = handshake(d, settle(d, t + 0.1), 0)
    d.write("controlword", 0x0F | Controlword.HALT, t + 0.5)
    t = settle(d, t + 0.5)
    d.write("modes_of_operation", Mode.PROFILE_VELOCITY, t)
    d.write("modes_of_operation", Mode.PROFILE_POSITION, t)
    d.write("controlword", 0x0F, t)  # the mode change dropped it
    assert not d.is_moving(t + 0.1)


def test_a_new_set_point_is_ignored_while_halt_is_set() -> None:
    d = device()
    t = pp(d)
    d.write("controlword", 0x0F | Controlword.HALT, t)
    d.write("target_position", 1_000, t)
    d.write("controlword", 0x1F | Controlword.HALT, t)
    assert not d.statusword(t) & Statusword.SET_POINT_ACKNOWLEDGE
    assert not d.is_moving(t + 0.1)


def test_a_set_point_without_speed_is_taken_but_never_reached() -> None:
    d = device(profile_velocity=0)
    t = handshake(d, pp(d), 1_000)
    assert not d.is_moving(t + 1)
    assert not d.statusword(t + 1) & Statusword.TARGET_REACHED


# -- profile velocity --------------------------------------------------------------------------


def test_pv_runs_at_the_target_velocity_and_halt_stops_and_resumes() -> None:
    d = device(profile_acceleration=20_000, profile_deceleration=40_000)
    t = enable(d)
    d.write("modes_of_operation", Mode.PROFILE_VELOCITY, t)
    assert d.statusword(t) & Statusword.SPEED_ZERO
    d.write("target_velocity", -10_000, t)
    assert not d.statusword(t + 0.25) & (Statusword.TARGET_REACHED | Statusword.SPEED_ZERO)
    assert d.read("velocity_actual_value", t + 0.25) == -5_000
    assert d.statusword(t + 0.5) & Statusword.TARGET_REACHED
    assert d.read("velocity_actual_value", t + 1) == -10_000
    d.write("target_velocity", 10_000, t + 1)  # reverse: brake, then accelerate
    assert d.read("velocity_actual_value", t + 1.25) == 0
    assert d.read("velocity_actual_value", t + 2) == 10_000
    d.write("controlword", 0x0F | Controlword.HALT, t + 2)
    assert not d.statusword(t + 2.1) & Statusword.TARGET_REACHED
    word = d.statusword(t + 2.3)
    assert word & Statusword.TARGET_REACHED and word & Statusword.SPEED_ZERO
    assert d.state_at(t + 2.3) is State.OPERATION_ENABLED
    d.write("controlword", 0x0F, t + 3)
    assert d.read("velocity_actual_value", t + 4) == 10_000
    d.write("target_velocity", 0, t + 4)
    assert d.statusword(t + 4.3) & Statusword.TARGET_REACHED


# -- stops ----------------------------------------------------------------------------------------


@pytest.mark.parametrize(("option", "end"), [(2, State.SWITCH_ON_DISABLED),
                                             (6, State.QUICK_STOP_ACTIVE)])
def test_quick_stop_ramps_on_the_quick_stop_deceleration(option: int, end: State) -> None:
    d = device(quick_stop_option_code=option, quick_stop_deceleration=100_000,
               profile_deceleration=10_000)
    t = handshake(d, pp(d), 45_000)
    t += 1.0
    assert d.read("velocity_actual_value", t) == 10_000
    d.write("controlword", 0x02, t)
    assert d.state_at(t + 0.05) is State.QUICK_STOP_ACTIVE
    assert d.read("velocity_actual_value", t + 0.05) == 5_000
    assert not d.statusword(t + 0.05) & Statusword.QUICK_STOP  # active low
    assert d.state_at(t + 0.2) is end
    assert not d.is_moving(t + 0.2)
    d.write("controlword", 0x0F, t + 0.3)
    assert d.state_at(t + 0.3) is (State.OPERATION_ENABLED if option == 6 else end)


def test_shutdown_releases_the_motor_at_once_and_disable_operation_ramps() -> None:
    d = device(profile_deceleration=10_000)
    t = handshake(d, pp(d), 45_000) + 1.0
    d.write("controlword", 0x06, t)
    assert d.state_at(t) is State.READY_TO_SWITCH_ON
    assert not d.is_moving(t)
    t = handshake(d, enable(d, t), 45_000) + 1.0
    d.write("controlword", 0x07, t)
    assert d.state_at(t) is State.SWITCHED_ON
    assert d.is_moving(t + 0.5) and not d.is_moving(t + 1.0)


def test_a_fault_stops_the_motor_and_only_a_fault_reset_clears_it() -> None:
    d = device(quick_stop_deceleration=50_000)
    t = handshake(d, pp(d), 45_000) + 1.0
    d.raise_fault(0x7500, t)
    assert d.state_at(t + 0.1) is State.FAULT_REACTION_ACTIVE
    assert d.state_at(t + 0.2) is State.FAULT
    assert not d.is_moving(t + 0.2)
    assert d.read("error_code", t + 0.2) == 0x7500
    for word in (0x06, 0x07, 0x0F, 0x8F):  # no edge of bit 7 (0x0F had it low... then 0x8F)
        d.write("controlword", word, t + 0.3)
    assert d.state_at(t + 0.3) is State.SWITCH_ON_DISABLED  # 0x8F after 0x0F is an edge
    assert d.read("error_code", t + 0.3) == 0
    d.raise_fault(0x7500, t + 0.4)
    d.write("controlword", 0x80, t + 0.5)  # bit 7 held from before: no edge
    assert d.state_at(t + 0.5) is State.FAULT
    t = enable(d, t + 0.5)
    assert d.state_at(t) is State.OPERATION_ENABLED


# -- limit switches --------------------------------------------------------------------------------


def _beyond(d: Cia402Device, t0: float, t1: float, limit: float, sign: int) -> float:
    """How far (physically) the axis went past ``limit`` in [t0, t1] (sampled every 1 ms)."""
    worst = -math.inf
    t = t0
    while t <= t1:
        worst = max(worst, sign * (d.physical_position(t) - limit))
        d.advance(t)
        t += 0.001
    return worst


def test_pp_stops_at_a_limit_switch_and_never_moves_further_into_it() -> None:
    d = device(profile_velocity=20_000, quick_stop_deceleration=1_000_000)
    t = handshake(d, pp(d), 80_000)
    overshoot = _beyond(d, t, t + 5, 50_000, +1)
    assert 0 <= overshoot <= 20_000**2 / (2 * 1_000_000) + 1  # the quick stop ramp, no more
    t = settle(d, t + 5)
    word = d.statusword(t)
    assert word & Statusword.INTERNAL_LIMIT_ACTIVE and word & Statusword.TARGET_REACHED
    assert d.read("digital_inputs", t) == DigitalInput.POSITIVE_LIMIT | DigitalInput.HOME_SWITCH
    p = d.physical_position(t)
    t = handshake(d, t, 60_000)  # further in: refused
    assert not d.is_moving(t + 0.1) and d.physical_position(t + 0.1) == p
    t = handshake(d, t + 0.1, 0)  # away: allowed
    assert d.read("position_actual_value", settle(d, t)) == 0
    assert not d.statusword(t + 5) & Statusword.INTERNAL_LIMIT_ACTIVE


def test_pv_stops_at_a_limit_switch_and_will_not_run_into_it() -> None:
    d = device(quick_stop_deceleration=500_000)
    t = enable(d)
    d.write("modes_of_operation", Mode.PROFILE_VELOCITY, t)
    d.write("target_velocity", -30_000, t)
    assert _beyond(d, t, t + 3, -50_000, -1) <= 30_000**2 / (2 * 500_000) + 1
    t = settle(d, t + 3)
    assert d.statusword(t) & Statusword.INTERNAL_LIMIT_ACTIVE
    d.write("target_velocity", -1_000, t)
    assert not d.is_moving(t + 0.5)
    d.write("target_velocity", 1_000, t + 0.5)
    assert d.read("velocity_actual_value", t + 1.0) == 1_000


@settings(deadline=None, max_examples=40)
@given(st.lists(st.tuples(st.integers(-200_000, 200_000), st.integers(10_000, 60_000),
                          st.booleans()), min_size=1, max_size=6))
def test_no_sequence_of_set_points_runs_past_a_limit_switch(moves: list[tuple[int, int, bool]],
                                                           ) -> None:
    qsd = 2_000_000
    d = device(quick_stop_deceleration=qsd, profile_acceleration=200_000,
               profile_deceleration=200_000)
    t = pp(d)
    worst = -math.inf

    def poll(t: float) -> int:
        nonlocal worst
        word = d.statusword(t)
        worst = max(worst, abs(d.physical_position(t)) - 50_000)
        return word

    for target, speed, immediate in moves:
        d.write("profile_velocity", speed, t)
        d.write("target_position", target, t)
        hs = SetPointHandshake(immediate=immediate)
        while not hs.accepted:
            word = hs.controlword(poll(t))
            if word is not None:
                d.write("controlword", word, t)
            t += 0.001
            assert t < 100
        for _ in range(300):
            poll(t)
            t += 0.001
    assert worst <= 60_000**2 / (2 * qsd) + 1  # the quick stop ramp from the top speed


# -- homing ---------------------------------------------------------------------------------------

CAM = dict(LIMITS, home_switch=10_000.0, increments_per_rev=10_000, index_offset=2_500.0)
DOG = dict(CAM, home_switch_width=10_000.0)  # the home switch covers 10000..20000

# method: the home position (physical) on the rig it runs on.
HOMES = {
    1: -47_500.0, 17: -50_000.0, 2: 42_500.0, 18: 50_000.0,
    3: 2_500.0, 19: 10_000.0, 4: 12_500.0, 20: 10_000.0,
    5: 12_500.0, 21: 10_000.0, 6: 2_500.0, 22: 10_000.0,
    7: 2_500.0, 23: 10_000.0, 8: 12_500.0, 24: 10_000.0,
    9: 12_500.0, 25: 20_000.0, 10: 22_500.0, 26: 20_000.0,
    11: 22_500.0, 27: 20_000.0, 12: 12_500.0, 28: 20_000.0,
    13: 12_500.0, 29: 10_000.0, 14: 2_500.0, 30: 10_000.0,
}


def _rig(method: int) -> Cia402Setup:
    m = homing_method(method)
    if m.home_switch in (HomeSwitch.LOWER_EDGE, HomeSwitch.UPPER_EDGE):
        return Cia402Setup(**DOG)
    cam = "negative" if m.home_switch is HomeSwitch.NEGATIVE else "positive"
    return Cia402Setup(**CAM, home_cam=cam)


def home(d: Cia402Device, method: int, t: float = 0.0, offset: int = 0) -> tuple[float, float]:
    """Run homing ``method`` from rest at ``t``; (the time it ended, how far the axis went
    past the limit switches it may not meet)."""
    m = homing_method(method)
    for name, value in (("homing_method", method), ("home_offset", offset),
                        ("homing_speed_search", 20_000), ("homing_speed_zero", 2_000),
                        ("homing_acceleration", 200_000)):
        d.write(name, value, t)
    t = enable(d, t)
    d.write("modes_of_operation", Mode.HOMING, t)
    d.write("controlword", 0x1F, t)
    worst = -math.inf
    start = t
    while homing_status(d.statusword(t)) is HomingStatus.IN_PROGRESS or d.is_moving(t):
        x = d.physical_position(t)
        if HomeSignal.NEGATIVE_LIMIT not in m.limit_switches:
            worst = max(worst, -50_000 - x)
        if HomeSignal.POSITIVE_LIMIT not in m.limit_switches:
            worst = max(worst, x - 50_000)
        t += 0.004
        assert t - start < 60, f"homing {method} did not end"
    return t, worst


@pytest.mark.parametrize("method", sorted(HOMES))
@pytest.mark.parametrize("start", [-30_000, 5_000, 15_000, 30_000, -55_000, 55_000])
def test_homing_ends_on_the_methods_home_position(method: int, start: int) -> None:
    d = Cia402Device(replace(_rig(method), position=start), now=0.0)
    t, worst = home(d, method, offset=123)
    m = homing_method(method)
    status = homing_status(d.statusword(t))
    if (start < -50_000 and HomeSignal.NEGATIVE_LIMIT not in m.limit_switches) or (
            start > 50_000 and HomeSignal.POSITIVE_LIMIT not in m.limit_switches):
        return  # starting on a limit switch it may not meet: anything but passing it
    assert status is HomingStatus.COMPLETED, (method, start, status)
    assert worst < 0, "it met a limit switch the method does not use"
    home_reading = d.position(t) - (d.physical_position(t) - HOMES[method])
    assert home_reading == pytest.approx(123, abs=1e-6)
    rest = d.physical_position(t) - HOMES[method]  # it comes to rest beyond, moving final
    assert rest * m.final_direction > 0
    assert abs(rest) <= 2_000**2 / (2 * 200_000) + 1e-3  # from the zero speed, no faster
    assert d.homed


def _expected_home(m: HomingMethod, s: Cia402Setup) -> float:
    """Where method ``m`` homes on rig ``s`` (physical), from the method's definition."""
    assert s.home_switch is not None and s.limit_negative is not None
    assert s.limit_positive is not None
    if m.signal is HomeSignal.NEGATIVE_LIMIT:
        edge = s.limit_negative
    elif m.signal is HomeSignal.POSITIVE_LIMIT:
        edge = s.limit_positive
    elif m.home_switch is HomeSwitch.UPPER_EDGE:
        assert s.home_switch_width is not None
        edge = s.home_switch + s.home_switch_width
    else:
        edge = s.home_switch
    if not m.index_pulse:
        return edge
    k = (edge - s.index_offset) / s.increments_per_rev
    n = math.floor(k) + 1 if m.final_direction > 0 else math.ceil(k) - 1
    return s.index_offset + n * s.increments_per_rev


@settings(deadline=None, max_examples=60)
@given(st.sampled_from(sorted(HOMES)), st.integers(-45_000, 45_000),
       st.integers(-30_000, 20_000), st.integers(2_000, 15_000), st.integers(0, 9_999),
       st.integers(-(2**20), 2**20))
def test_homing_finds_its_home_from_anywhere_between_the_limits(
        method: int, start: int, switch: int, width: int, index: int, offset: int) -> None:
    m = homing_method(method)
    dog = m.home_switch in (HomeSwitch.LOWER_EDGE, HomeSwitch.UPPER_EDGE)
    s = Cia402Setup(**LIMITS, position=start, home_switch=float(switch),
                    home_switch_width=float(width) if dog else None,
                    home_cam="negative" if m.home_switch is HomeSwitch.NEGATIVE else "positive",
                    index_offset=float(index))
    d = Cia402Device(s, now=0.0)
    t, worst = home(d, method, offset=offset)
    assert homing_status(d.statusword(t)) is HomingStatus.COMPLETED
    assert worst < 0
    found = d.position(t) - (d.physical_position(t) - _expected_home(m, s))
    assert found == pytest.approx(offset, abs=1e-6)


@pytest.mark.parametrize("method", [33, 34])
@pytest.mark.parametrize("start", [-7_000, 2_500, 4_000])
def test_index_pulse_homing_takes_the_next_pulse_in_its_direction(method: int,
                                                                 start: int) -> None:
    d = Cia402Device(replace(SETUP, position=start), now=0.0)
    t, _ = home(d, method)
    assert homing_status(d.statusword(t)) is HomingStatus.COMPLETED
    f = homing_method(method).final_direction
    expected = [p for p in range(-47_500, 50_000, 10_000) if (p - start) * f > 0]
    pulse = min(expected, key=lambda p: abs(p - start))
    assert d.position(t) - (d.physical_position(t) - pulse) == pytest.approx(0, abs=1e-6)


@pytest.mark.parametrize("method", [35, 37])
def test_current_position_homing_sets_the_home_offset_without_moving(method: int) -> None:
    d = Cia402Device(replace(SETUP, position=4_321), now=0.0)
    t, _ = home(d, method, offset=-10)
    assert homing_status(d.statusword(t)) is HomingStatus.COMPLETED
    assert d.read("position_actual_value", t) == -10
    assert d.physical_position(t) == 4_321


def test_homing_meets_a_limit_switch_it_does_not_use_and_stops_with_an_error() -> None:
    # Method 19 expects the home switch on the positive side; here it is on the negative
    # side (wired for method 21): from inside, it runs away from the edge into a limit.
    d = Cia402Device(replace(SETUP, home_cam="negative", position=0), now=0.0)
    t, worst = home(d, 19)
    assert homing_status(d.statusword(t)) is HomingStatus.ERROR_STOPPED
    assert not d.homed
    assert 0 <= worst <= 20_000**2 / (2 * 1_000_000) + 1  # stopped on the quick stop ramp


def test_homing_halt_and_bit_4_falling_interrupt_it() -> None:
    d = Cia402Device(SETUP, now=0.0)
    d.write("homing_method", 17, 0.0)
    t = enable(d)
    d.write("modes_of_operation", Mode.HOMING, t)
    d.write("controlword", 0x1F, t)
    assert homing_status(d.statusword(t + 0.5)) is HomingStatus.IN_PROGRESS
    d.write("controlword", 0x11F, t + 0.5)
    t = settle(d, t + 0.5)
    assert homing_status(d.statusword(t)) is HomingStatus.INTERRUPTED
    d.write("controlword", 0x0F, t)
    d.write("controlword", 0x1F, t)
    d.write("controlword", 0x0F, t + 0.5)
    t = settle(d, t + 0.5)
    assert homing_status(d.statusword(t)) is HomingStatus.INTERRUPTED
    assert not d.homed


def test_homing_with_no_method_or_speed_is_an_error() -> None:
    d = Cia402Device(SETUP, now=0.0)
    t = enable(d)
    d.write("modes_of_operation", Mode.HOMING, t)
    d.write("controlword", 0x1F, t)
    assert homing_status(d.statusword(t)) is HomingStatus.ERROR_STOPPED


# -- objects and power --------------------------------------------------------------------------


def test_refusals_carry_the_given_exception_codes() -> None:
    d = Cia402Device(SETUP, codes=ExceptionCodes(address=0x12, access=0x13, value=0x14),
                     now=0.0)
    cases = [
        (lambda: d.read("no_such_object", 0.0), 0x12),
        (lambda: d.write("statusword", 0, 0.0), 0x13),
        (lambda: d.write("position_actual_value", 0, 0.0), 0x13),
        (lambda: d.write("controlword", 0x10000, 0.0), 0x14),
        (lambda: d.write("target_position", 2**31, 0.0), 0x14),
        (lambda: d.write("profile_velocity", -1, 0.0), 0x14),
        (lambda: d.write("modes_of_operation", Mode.CYCLIC_SYNC_POSITION, 0.0), 0x14),
        (lambda: d.write("homing_method", 16, 0.0), 0x14),
        (lambda: d.write("quick_stop_option_code", 9, 0.0), 0x14),
        (lambda: d.check("homing_method", 36), 0x14),
    ]
    for call, code in cases:
        with pytest.raises(SlaveException) as info:
            call()
        assert info.value.code == code
    assert d.read("supported_drive_modes", 0.0) == 0x25
    d.check("homing_method", -0)  # accepted, nothing written
    assert d.read("target_position", 0.0) == 0


def test_power_loss_forgets_volatile_objects_and_starts_switch_on_disabled() -> None:
    d = Cia402Device(SETUP, retained={"home_offset"}, defaults={"profile_velocity": 7_000},
                     now=0.0)
    assert d.read("profile_velocity", 0.0) == 7_000
    t = handshake(d, pp(d), 20_000)
    d.write("profile_velocity", 3_000, t)
    d.write("home_offset", 55, t)
    d.write("homing_method", 35, t)
    d.power_loss(t + 0.5)
    assert not d.is_moving(t + 0.6)
    where = d.physical_position(t + 0.6)
    d.power_restore(t + 1)
    assert d.state_at(t + 1) is State.SWITCH_ON_DISABLED
    assert d.read("profile_velocity", t + 1) == 7_000
    assert d.read("home_offset", t + 1) == 55
    assert d.read("homing_method", t + 1) == 0
    assert d.read("modes_of_operation_display", t + 1) == 0
    assert d.read("position_actual_value", t + 1) == 0  # incremental encoder
    assert d.physical_position(t + 1) == where
    assert not d.homed
