"""CiA 402 logic (drives/cia402.py) and the simulated CiA 402 device (sim/cia402_device.py)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivebus.drives.cia402 import (
    COMMAND_WORDS,
    HOMING_METHODS,
    MAX_STEPS,
    OBJECTS,
    Command,
    Controlword,
    HomeSignal,
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
