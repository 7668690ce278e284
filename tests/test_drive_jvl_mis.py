"""The JVL MIS integrated stepper (configs/drives/jvl_mis.toml), a drive written from its
public manual by a user who never saw it: a machine on its generic twin, driven through the
public API (enable, move_to, jog, stop, halt_now, home, reset, status), judged by the twin
and the wire log, not by the axis's own view.

The manual's link rules (ch. 11, pp. 261-262): function codes 03 and 16 only, every
register 32 bits at twice its number (so every request starts at an even address and
spans an even count), at most 16 registers a transfer. Its position mode runs to P_SOLL
as soon as it is entered, so the enable writes P_SOLL = P_IST before it enters it."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Any

import anyio
import anyio.lowlevel
import pytest

from drivebus import AxisState, open_machine
from drivebus.errors import DrivebusError, MotionAborted, NotSupported
from waits import until
from wirelog import request_pdus

ROOT = Path(__file__).resolve().parents[1]
JVL = ROOT / "configs" / "drives" / "jvl_mis.toml"
P_SOLL, MODE_REG = 6, 4  # registers 3 and 2, at twice their numbers


def machine(tag: str) -> dict[str, Any]:
    return {"name": f"jvl-{tag}",
            "lines": {"l": {"port": f"sim://jvl-{tag}", "settings": "115200 8N1",
                            "timeout": 0.1}},
            "axes": {"a": {"line": "l", "address": 1, "drive": str(JVL),
                           "pulses_per_rev": 1600, "units_per_rev": 10.0, "speed": 20.0,
                           "accel": 200.0, "decel": 200.0, "limits": [-50.0, 50.0],
                           "poll": {"moving": 0.01, "idle": 0.05}}}}


def assert_the_manuals_link_rules(wire: Any) -> None:
    for pdu in request_pdus(wire):
        fc, address, count = pdu[0], int.from_bytes(pdu[1:3], "big"), int.from_bytes(
            pdu[3:5], "big")
        assert fc in (3, 16), pdu.hex(" ")
        assert address % 2 == 0 and count % 2 == 0 and count <= 16, pdu.hex(" ")


async def test_the_public_commands_on_the_twin() -> None:
    with anyio.fail_after(60):
        async with open_machine(machine("api")) as m:
            a, twin, wire = m.axes["a"], m.sim_drives["a"], m.wires["l"]
            await a.enable()
            assert twin.enabled and not twin.is_moving()
            await a.move_to(25.0)  # 2.5 rev = 4000 steps
            assert twin.position() == 4000 and not twin.is_moving()
            st = await a.refresh()
            assert st.in_position and not st.moving and a.position == pytest.approx(25.0)
            async with a.jogging(-5.0):
                await until(twin.is_moving, "the jog to run on the twin")
            assert not twin.is_moving() and a.state is AxisState.STANDSTILL
            await a.move_by(-10.0, speed=10.0)
            assert not twin.is_moving()
            task_done = anyio.Event()

            async def long_move() -> None:
                with contextlib.suppress(MotionAborted):  # the stop ends it
                    await a.move_to(-45.0, speed=10.0)
                task_done.set()

            async with anyio.create_task_group() as tg:
                tg.start_soon(long_move)
                await until(twin.is_moving, "the long move to run on the twin")
                await a.stop()
                assert not twin.is_moving()
                await task_done.wait()
            at = twin.position()
            await a.move_by(5.0)
            async with anyio.create_task_group() as tg:
                tg.start_soon(long_move)
                await until(twin.is_moving, "the long move to run on the twin")
                await a.halt_now()
                assert not twin.is_moving()
            assert twin.position() != at
            await a.reset()
            assert not twin.is_moving()
            await a.home()
            st = await a.refresh()
            assert st.homed and twin.position() == 0 and st.position == 0.0
            assert_the_manuals_link_rules(wire)


async def test_enable_moves_nothing_though_position_mode_runs_to_p_soll() -> None:
    """P_SOLL left far from the motor (another master, a power-up default): the enable
    writes P_SOLL = P_IST before MODE_REG = position, so the twin, which runs to P_SOLL as
    the mode is entered, stands."""
    with anyio.fail_after(30):
        async with open_machine(machine("enable")) as m:
            a, twin, wire = m.axes["a"], m.sim_drives["a"], m.wires["l"]
            twin.write_registers(P_SOLL, [8000, 0], 0.0)  # low word first: 8000 steps
            wire.clear_log()
            await a.enable()
            assert twin.enabled and not twin.is_moving() and twin.position() == 0
            writes = [(int.from_bytes(p[1:3], "big"), p[6:]) for p in request_pdus(wire)
                      if p[0] == 16]
            assert [w[0] for w in writes] == [P_SOLL, MODE_REG]
            assert writes[0][1][:4] == bytes(4)  # P_SOLL := P_IST (0), then position mode
            st = await a.refresh()
            assert st.enabled and not st.moving and not twin.is_moving()
            # the guard is needed: position mode entered with P_SOLL elsewhere runs there
            await a.disable()
            slave = a.profile.slave
            await slave.write_registers(P_SOLL, [800, 0])
            await slave.write_registers(MODE_REG, [2, 0])
            await until(twin.is_moving, "position mode to run to P_SOLL on the twin")
            await a.stop()


async def test_what_the_manual_does_not_give_is_refused_before_any_frame() -> None:
    with anyio.fail_after(30):
        async with open_machine(machine("refuse")) as m:
            a, wire = m.axes["a"], m.wires["l"]
            await a.enable()
            wire.clear_log()
            with pytest.raises(NotSupported, match="clears ERR_BITS"):
                await a.profile.clear_alarm()
            assert not [p for p in request_pdus(wire) if p[0] == 16]


async def test_homing_presets_a_negative_position() -> None:
    """The set homing writes the offset to P_IST (a signed 32-bit register, low word
    first); the twin's position becomes it, sign included."""
    cfg = machine("home")
    cfg["axes"]["a"]["homing"] = {"method": "set_here", "offset": -12.5}  # -2000 steps
    with anyio.fail_after(30):
        async with open_machine(cfg) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            await a.enable()
            await a.move_to(5.0)
            await a.home()
            assert twin.position() == -2000 and a.position == pytest.approx(-12.5)
            assert (await a.refresh()).homed


# -- the promises on this drive: a stop wins, a cancelled caller stops, a refusal sends
# nothing, leaving the machine leaves it at rest (as test_promises.py on the demo) -------


V_SOLL = 10  # register 5


def kinds(wire: Any, address: int, since: float) -> list[tuple[str, float]]:
    """Its starts (P_SOLL written, or velocity mode entered with V_SOLL not 0) and stops
    (V_SOLL = 0) after ``since``, with the time each began to leave."""
    out = []
    v_soll = bytes(4)
    for f in list(wire.log):
        if f.direction != "request" or f.address != address:
            continue
        pdu = f.data[1:-2]
        if pdu[0] != 16:
            continue
        at, first = int.from_bytes(pdu[1:3], "big"), pdu[6:10]
        kind = None
        if at == V_SOLL:
            v_soll = first
            kind = "stop" if first == bytes(4) else None
        elif at == P_SOLL or (at == MODE_REG and first[:2] == b"\x00\x01"
                              and v_soll != bytes(4)):
            kind = "start"
        if kind and f.start > since:
            out.append((kind, f.start))
    return out


def two_axes(tag: str) -> dict[str, Any]:
    cfg = machine(tag)
    cfg["axes"]["b"] = {**cfg["axes"]["a"], "address": 2}
    return cfg


@pytest.mark.parametrize("point", ["setup", "moving"])
@pytest.mark.parametrize("whose", ["its own", "a bystander's"])
async def test_a_stop_reaches_the_wire_within_one_transaction(point: str, whose: str) -> None:
    with anyio.fail_after(60):
        async with open_machine(two_axes(f"stop-{point}-{whose[0]}")) as m:
            a, b, wire = m.axes["a"], m.axes["b"], m.wires["l"]
            await a.enable()
            await b.enable()
            if whose != "its own":
                await b.jog(3.0, watchdog=None)
                await until(m.sim_drives["b"].is_moving, "the bystander to jog")
            stopper = a if whose == "its own" else b
            async with anyio.create_task_group() as tg:
                async def move() -> None:
                    with contextlib.suppress(MotionAborted):
                        await a.move_to(-45.0, speed=10.0)
                tg.start_soon(move)
                if point == "setup":
                    for _ in range(3):
                        await anyio.lowlevel.checkpoint()
                else:
                    await until(m.sim_drives["a"].is_moving, "the move to run")
                called = time.monotonic()
                await stopper.stop()
                if stopper is b:
                    tg.cancel_scope.cancel()
            frames = kinds(wire, stopper.config.address, called)
            stops = [t for k, t in frames if k == "stop"]
            if stops:
                between = sum(1 for f in list(wire.log)
                              if f.direction == "request" and called < f.start < stops[0])
                assert between <= 1, f"{between} requests left before the stop"
            assert not [t for k, t in frames if k == "start" and t > (stops or [called])[0]]
            assert not m.sim_drives[stopper.name].is_moving()
            assert not m.sim_drives["a"].is_moving()


@pytest.mark.parametrize("how", ["cancel", "exit", "exception"])
async def test_a_cancelled_caller_or_a_left_machine_leaves_the_motor_at_rest(how: str) -> None:
    twins: dict[str, Any] = {}
    with anyio.fail_after(60), contextlib.suppress(RuntimeError):
        async with open_machine(machine(f"leave-{how}")) as m:
            a, twins["a"] = m.axes["a"], m.sim_drives["a"]
            await a.enable()
            if how == "cancel":
                with anyio.move_on_after(60) as scope:
                    async with anyio.create_task_group() as tg:
                        tg.start_soon(a.move_to, -45.0)
                        await until(twins["a"].is_moving, "the move to run")
                        scope.cancel()
                assert not twins["a"].is_moving()
                return
            await a.jog(5.0, watchdog=None)
            await until(twins["a"].is_moving, "the jog to run")
            if how == "exception":
                raise RuntimeError("the owner fails")
    assert not twins["a"].is_moving()


async def test_a_refusal_sends_nothing() -> None:
    with anyio.fail_after(30):
        async with open_machine(machine("refusal")) as m:
            a, wire = m.axes["a"], m.wires["l"]
            await a.enable()
            await a.refresh()
            since = time.monotonic()
            for refused in (lambda: a.move_to(1000.0), lambda: a.move_by(-1e6),
                            lambda: a.move_to(10.0, speed=1e9)):
                with pytest.raises(DrivebusError):
                    await refused()
            await a.refresh()
            assert not [f for f in list(wire.log) if f.direction == "request"
                        and f.start > since and f.data[1] == 16]


async def test_a_move_of_a_disabled_axis_says_to_enable_it() -> None:
    """The motor powers up passive (MODE_REG 0): a move is refused before any frame,
    and the refusal says what to do (a technician's first `drivebus move` meets it)."""
    with anyio.fail_after(30):
        async with open_machine(machine("disabled")) as m:
            a, wire = m.axes["a"], m.wires["l"]
            await a.refresh()
            assert a.state is AxisState.DISABLED
            since = time.monotonic()
            with pytest.raises(DrivebusError, match=r"in state Disabled: enable it first"):
                await a.move_to(10.0)
            assert not [f for f in list(wire.log) if f.direction == "request"
                        and f.start > since and f.data[1] == 16]
