"""The judge (``drivebus.motion.judge``) without an event loop: every status a drive can
report, against every kind of motion, gives the verdict the axis's rules say."""

from __future__ import annotations

from dataclasses import dataclass, field

from hypothesis import given
from hypothesis import strategies as st

from drivebus.drives.base import HomingSwitches
from drivebus.drives.status import DriveStatus
from drivebus.errors import LimitViolation, MotionError
from drivebus.motion.judge import judge, judge_homing
from drivebus.motion.state import AxisState

LATE = 0.25


@dataclass
class M:
    """A motion as the judge reads it."""

    kind: str = "move"
    what: str = "move to 10"
    direction: int = 1
    start: int | None = 0
    target: int | None = 1000
    accepted_at: float | None = 1.0
    seen_motion: bool = False
    both_ways: bool = False
    switches: HomingSwitches = field(default_factory=HomingSwitches)
    overrun: float = 50.0
    switch_seen: dict[int, int] = field(default_factory=dict)
    switch_left: set[int] = field(default_factory=set)


def status(**kw: object) -> DriveStatus:
    base: dict[str, object] = {"enabled": True, "moving": False, "in_position": False,
                               "homed": False, "alarm": False, "position": 0}
    base.update(kw)
    return DriveStatus(**base)  # type: ignore[arg-type]


def run(m: M, st: DriveStatus, issued: float = 1.1):
    return judge("x", m, st, issued, tolerance=1, late_after=LATE, where="0.0000")


def test_a_move_at_rest_in_position_on_its_target_has_arrived() -> None:
    v = run(M(seen_motion=True), status(position=1000, in_position=True))
    assert v.outcome == "arrived" and v.state is AxisState.STANDSTILL and v.error is None


def test_a_move_on_its_target_not_yet_in_position_is_settling() -> None:
    assert run(M(seen_motion=True), status(position=1000)).outcome == "going"


def test_a_drive_that_stopped_short_fails_the_move_and_may_have_been_reset() -> None:
    v = run(M(seen_motion=True), status(position=400, in_position=True))
    assert v.outcome == "failed" and isinstance(v.error, MotionError)
    assert "short of the move to 10" in str(v.error) and v.check_settings


def test_a_move_not_started_has_a_moment_then_fails() -> None:
    assert run(M(), status(position=0), issued=1.1).outcome == "going"
    late = run(M(), status(position=0), issued=1.0 + LATE + 0.01)
    assert late.outcome == "failed" and "did not start" in str(late.error)


@given(direction=st.sampled_from([1, -1]), moving=st.booleans(), seen=st.booleans())
def test_a_limit_switch_ahead_of_a_started_motion_ends_it_with_a_stop(
        direction: int, moving: bool, seen: bool) -> None:
    m = M(direction=direction, seen_motion=seen or moving, target=direction * 5000)
    sw = {"limit_positive": direction > 0, "limit_negative": direction < 0}
    v = run(m, status(moving=moving, position=direction * 300, **sw))
    assert v.outcome == "failed" and isinstance(v.error, LimitViolation)
    assert v.state is AxisState.ERROR_STOP and v.stop.endswith("limit switch")


@given(position=st.integers(-10_000, 10_000), moving=st.booleans(),
       in_position=st.booleans(), pos_switch=st.booleans(), neg_switch=st.booleans(),
       seen=st.booleans(), issued=st.floats(1.0001, 5.0))
def test_no_status_ever_lets_a_motion_arrive_off_target_or_moving(
        position: int, moving: bool, in_position: bool, pos_switch: bool,
        neg_switch: bool, seen: bool, issued: float) -> None:
    m = M(seen_motion=seen)
    v = run(m, status(position=position, moving=moving, in_position=in_position,
                      limit_positive=pos_switch, limit_negative=neg_switch), issued)
    if v.outcome == "arrived":
        assert not moving and in_position and abs(position - 1000) <= 1
    if moving:
        assert v.seen_motion
    if v.outcome == "failed" and v.state is AxisState.ERROR_STOP:
        assert v.stop


def test_a_jog_to_the_soft_limit_is_done_at_rest_there() -> None:
    v = run(M(kind="jog", what="jog at 5", seen_motion=True), status(position=1000))
    assert v.outcome == "done" and "soft limit" in v.note


def test_a_speed_run_the_drive_ended_itself_is_over_and_may_hide_a_reset() -> None:
    v = run(M(kind="jog", what="jog at 5", target=None, seen_motion=True),
            status(position=700))
    assert v.outcome == "done" and v.check_settings


def homing(**kw: object) -> M:
    return M(kind="home", what="homing", direction=0, target=None, **kw)  # type: ignore[arg-type]


def test_a_homing_error_ends_the_homing_at_once_even_from_the_first_status() -> None:
    v = judge_homing("x", homing(), status(homing_error=True, moving=True), 1.01,
                     late_after=LATE, where="0.0000")
    assert v.outcome == "failed" and "homing error" in str(v.error)
    assert v.state is AxisState.ERROR_STOP and v.stop == "homing error"


def test_a_homing_is_done_only_homed_at_rest_and_no_longer_homing() -> None:
    def verdict(**kw: object) -> str:
        return judge_homing("x", homing(), status(**kw), 2.0, late_after=LATE,
                            where="0").outcome

    assert verdict(homed=True) == "done"
    assert verdict(homed=True, homing=True) == "going"
    assert verdict(homed=True, moving=True) == "going"
    assert verdict(homed=False) == "going"


def test_a_homing_meeting_a_switch_it_does_not_use_fails() -> None:
    v = judge_homing("x", homing(seen_motion=True), status(moving=True, limit_negative=True),
                     2.0, late_after=LATE, where="0")
    assert v.outcome == "failed" and "does not use it" in str(v.error)


def test_a_homing_may_brake_into_its_reversal_switch_but_not_meet_it_again() -> None:
    m = homing(switches=HomingSwitches(reverses_at=frozenset({1})), seen_motion=True)
    braking = judge_homing("x", m, status(moving=True, limit_positive=True, position=100),
                           2.0, late_after=LATE, where="0")
    assert braking.outcome == "going" and braking.switch_seen == {1: 100}
    m.switch_seen = dict(braking.switch_seen)
    left = judge_homing("x", m, status(moving=True, position=40), 2.1, late_after=LATE,
                        where="0")
    assert left.switch_left == {1}
    m.switch_left = set(left.switch_left)
    again = judge_homing("x", m, status(moving=True, limit_positive=True, position=90),
                         2.2, late_after=LATE, where="0")
    assert again.outcome == "failed" and "no home switch" in str(again.error)
