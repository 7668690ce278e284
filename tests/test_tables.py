"""Drive position tables: the NT86's multi-segment mode (manual 3.7.4) run by its twin,
written first and started by one command; other drives say why they cannot."""

from __future__ import annotations

import math
from pathlib import Path

import anyio
import pytest

from drivebus import AxisState, open_machine
from drivebus.errors import MotionAborted, NotSupported
from drivebus.motion import Machine

DEMO = Path(__file__).resolve().parents[1] / "configs" / "demo.toml"


def writes(m: Machine, since: int) -> list[tuple[float, int, int]]:
    """(time, register, first value) of each write request to x (NT86, address 2)."""
    out = []
    for f in list(m.wires["rs485"].log)[since:]:
        if f.direction == "request" and f.address == 2 and f.data[1] in (6, 16):
            out.append((f.end, int.from_bytes(f.data[2:4], "big"),
                        int.from_bytes(f.data[4:6] if f.data[1] == 6 else f.data[7:9], "big")))
    return out


def rests(twin: object, t0: float, t1: float) -> list[float]:
    """Where the twin stood still between its motions (pulses), in order."""
    out = []
    for s in twin.kin.trace(t0, t1):  # type: ignore[attr-defined]
        if s.v0 == 0 and s.a == 0 and s.t0 > t0:
            out.append(round(s.p0))
    return out


async def test_a_table_runs_with_no_command_between_its_moves() -> None:
    async with open_machine(DEMO) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]
        targets = [30.0, 60.0, 45.0, 90.0]
        mark = len(m.wires["rs485"].log)
        t0 = anyio.current_time()
        await x.run_table(targets, dwell=0.05, trigger_input="IN5")
        t1 = anyio.current_time()
        assert twin.position() == x.units.to_pulses(90.0)
        assert rests(twin, t0, t1)[:4] == [x.units.to_pulses(t) for t in targets]
        sent = writes(m, mark)
        trigger = sent[-1]
        assert trigger[1] == 64 and trigger[2] & 0x20  # IN5's polarity bit: USER3 active
        first_motion = min(s.t0 for s in twin.kin.trace(t0, t1) if s.v0 or s.a)
        assert trigger[0] <= first_motion  # everything was written before it started
        # the dwells between its moves (not the rest after the last one, which lasts: the
        # call may return well after it began on a busy machine)
        standing = [s.duration for s in twin.kin.trace(t0, t1)
                    if s.v0 == 0 and s.a == 0 and first_motion < s.t0
                    and math.isfinite(s.duration)]
        assert standing and all(d == pytest.approx(0.05, abs=1e-6) for d in standing)
        assert twin.params[20] == 20  # armed until the next command
        await x.move_to(20.0)
        assert twin.params[20] == 0 and twin.position() == x.units.to_pulses(20.0)


@pytest.mark.parametrize("stopper", ["stop", "halt_now"])
async def test_a_stop_ends_a_table_and_nothing_of_it_runs_after(stopper: str) -> None:
    async with open_machine(DEMO) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]
        mark = len(m.wires["rs485"].log)
        outcome: list[BaseException] = []

        async def table() -> None:
            try:
                await x.run_table([100.0, 20.0, 200.0, 10.0], trigger_input="IN5")
            except MotionAborted as exc:
                outcome.append(exc)

        async with anyio.create_task_group() as tg:
            tg.start_soon(table)
            async for st in x.watch():
                if st.moving and st.position is not None and st.position > 40_000:
                    break  # past 100 mm: on its second row
            await getattr(x, stopper)()
            assert not twin.is_moving()
        assert outcome and x.state is AxisState.STANDSTILL
        stop_at = next(t for t, reg, v in writes(m, mark) if reg == 18 and v in (5, 6))
        assert not [w for w in writes(m, mark) if w[0] > stop_at and 60 <= w[1] <= 65
                    and w[2] & 0x20]  # the table's start never again after the stop
        here, polls = twin.position(), 0
        async for st in x.watch():  # five more polls: the drive stays where it stopped
            assert not st.moving and not twin.is_moving() and twin.position() == here
            polls += 1
            if polls == 5:
                break


@pytest.mark.parametrize(("name", "why"), [
    ("y", r"BHSS.*PT\) sequencer"),
    ("z", r"CL86R.*function 11"),
    ("r", r"EPR60.*does not describe"),
])
async def test_a_drive_without_a_modbus_table_says_why(name: str, why: str) -> None:
    async with open_machine(DEMO) as m:
        with pytest.raises(NotSupported, match=why):
            await m.axes[name].run_table([10.0, 20.0], trigger_input="X3"
                                         if name != "r" else "IN5")
        assert m.axes[name].state is AxisState.STANDSTILL
