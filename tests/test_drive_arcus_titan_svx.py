"""The Arcus TITAN-SVX servo controller (tests/drives/arcus_titan_svx.toml), a drive written
from its public manual by a user who never saw it (a test description, not shipped: the
pages of its manual read give two of its Modbus addresses, the rest is inferred): a
machine on its generic twin, driven through the public API (enable, move_to, jog, stop,
halt_now, home, reset, status), judged by the twin and the wire log, not by the axis's own
view.

The manual's link rules (TITAN-SVX Software Manual Rev 4.01, ch. 4, pp. 14-15): function
codes 1, 2, 3, 5, 8 and 16 only; FC03 and FC16 "only a pair of a register", from an even
address; FC01 reads coils 0..6 only, so the command coils (Servo On is coil 104, p. 19)
cannot be read back; a 32-bit variable goes high word first (p. 19, Table 4.5)."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Any

import anyio
import anyio.lowlevel
import pytest

from drivebus import AxisState, open_machine
from drivebus.errors import DrivebusError, ModbusException, MotionAborted, NotSupported
from waits import until
from wirelog import request_pdus

ROOT = Path(__file__).resolve().parents[1]
SVX = ROOT / "tests" / "drives" / "arcus_titan_svx.toml"
EX, VX, HSPD, DEC, TARGET = 0, 6, 20, 24, 26  # the 32-bit variables' (even) addresses
SVON, STOPX, ABORTX, MOVEX, JOG_PLUS, JOG_MINUS = 104, 106, 107, 109, 110, 111


def machine(tag: str) -> dict[str, Any]:
    return {"name": f"svx-{tag}",
            "lines": {"l": {"port": f"sim://svx-{tag}", "settings": "115200 8N1",
                            "timeout": 0.1}},
            "axes": {"a": {"line": "l", "address": 1, "drive": str(SVX),
                           "pulses_per_rev": 10000, "units_per_rev": 10.0, "speed": 20.0,
                           "accel": 200.0, "decel": 200.0, "limits": [-50.0, 50.0],
                           "poll": {"moving": 0.01, "idle": 0.05}}}}


def assert_the_manuals_link_rules(wire: Any) -> None:
    """FC03/FC16 a pair from an even address; FC05 FF00h on a command coil; FC01 only at
    coils 0..6; nothing else."""
    for pdu in request_pdus(wire):
        fc, address = pdu[0], int.from_bytes(pdu[1:3], "big")
        assert fc in (1, 2, 3, 5, 16), pdu.hex(" ")
        if fc in (3, 16):
            assert address % 2 == 0 and int.from_bytes(pdu[3:5], "big") == 2, pdu.hex(" ")
        elif fc == 5:
            assert pdu[3:5] == b"\xff\x00", pdu.hex(" ")
        elif fc == 1:
            assert address + int.from_bytes(pdu[3:5], "big") <= 7, pdu.hex(" ")


def coils_forced(wire: Any, since: float = 0.0) -> list[int]:
    return [int.from_bytes(p[1:3], "big") for p in request_pdus(wire, since) if p[0] == 5]


async def test_the_public_commands_on_the_twin() -> None:
    with anyio.fail_after(60):
        async with open_machine(machine("api")) as m:
            a, twin, wire = m.axes["a"], m.sim_drives["a"], m.wires["l"]
            st = await a.refresh()
            assert not st.enabled and not st.in_position  # MST 0x0 at power-up (p. 34)
            await a.enable()
            assert twin.enabled and not twin.is_moving()
            assert coils_forced(wire) == [SVON]
            await a.move_to(25.0)  # 2.5 rev = 25 000 counts
            assert twin.position() == 25000 and not twin.is_moving()
            st = await a.refresh()
            assert st.in_position and not st.moving and a.position == pytest.approx(25.0)
            assert st.raw["ex"] == 25000 and st.raw["mst"] == 0b0011  # enabled, in position
            async with a.jogging(-5.0):
                await until(twin.is_moving, "the jog to run on the twin")
                st = await a.refresh()
                assert st.moving and st.velocity_rpm is not None and st.velocity_rpm < 0
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
                since = time.monotonic()
                await a.stop()
                assert not twin.is_moving()
                assert STOPX in coils_forced(wire, since)
                await task_done.wait()
            at = twin.position()
            await a.move_by(5.0)
            async with anyio.create_task_group() as tg:
                tg.start_soon(long_move)
                await until(twin.is_moving, "the long move to run on the twin")
                since = time.monotonic()
                await a.halt_now()
                assert not twin.is_moving()
                assert ABORTX in coils_forced(wire, since)
            assert twin.position() != at
            await a.reset()
            assert not twin.is_moving()
            await a.home()
            st = await a.refresh()
            assert st.homed and twin.position() == 0 and st.position == 0
            assert_the_manuals_link_rules(wire)


async def test_a_set_homing_completes_without_a_homed_flag() -> None:
    """The TITAN's MST has no homed bit (p. 34): the home is a write of EX (p. 32), a
    position that is the offset at once. The axis's home() returns, homed, instead of
    waiting for a flag the drive does not have."""
    cfg = machine("home")
    cfg["axes"]["a"]["homing"] = {"method": "set_here", "offset": -12.5}  # -12 500 counts
    with anyio.fail_after(30):
        async with open_machine(cfg) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            await a.enable()
            await a.move_to(5.0)
            assert not (await a.refresh()).homed
            with anyio.fail_after(5):
                await a.home()
            assert twin.position() == -12500 and a.position == pytest.approx(-12.5)
            assert (await a.refresh()).homed


async def test_status_decodes_through_scale_and_unit() -> None:
    """VX is rpm, EX encoder counts: a jog at 6 units/s (0.6 rev/s = 36 rpm) shows 36 rpm
    and a position in units; DriveStatus.raw keeps each polled register's own value."""
    with anyio.fail_after(30):
        async with open_machine(machine("units")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            await a.enable()
            await a.jog(6.0, watchdog=None)
            await until(lambda: twin.speed_rpm() == pytest.approx(36.0),
                        "the jog to reach its speed on the twin")
            st = await a.refresh()
            assert st.velocity_rpm == pytest.approx(36.0) and st.raw["vx"] == 36
            await a.stop()
            st = await a.refresh()
            assert st.position == twin.position() == st.raw["ex"]
            assert a.position == pytest.approx(twin.position() / 1000.0)


async def test_what_the_drive_cannot_is_refused_before_any_frame() -> None:
    with anyio.fail_after(30):
        async with open_machine(machine("refuse")) as m:
            a, wire = m.axes["a"], m.wires["l"]
            await a.enable()
            await a.refresh()
            since = time.monotonic()
            for refused in (a.zero_position, a.profile.save_parameters,
                            lambda: a.set_output("OUT1", True)):
                with pytest.raises(NotSupported):
                    await refused()
            with pytest.raises(DrivebusError):
                await a.move_to(1000.0)  # beyond the soft limit
            with pytest.raises(DrivebusError):
                await a.move_to(10.0, speed=1e9)  # HSPD's range
            assert not [p for p in request_pdus(wire, since) if p[0] in (5, 16)]


async def test_the_twin_keeps_the_manuals_link_rules() -> None:
    """What the manual says the drive refuses, the twin refuses: a read of more than a
    pair or from an odd address (p. 15), a function it does not serve (FC06: p. 14), a
    read of a command coil (FC01 serves coils 0..6: p. 15)."""
    with anyio.fail_after(30):
        async with open_machine(machine("rules")) as m:
            slave = m.axes["a"].profile.slave
            assert await slave.read_holding_registers(EX, 2) == [0, 0]
            for bad in (lambda: slave.read_holding_registers(EX, 4),
                        lambda: slave.read_holding_registers(EX + 1, 2),
                        lambda: slave.read_holding_registers(EX, 1),
                        lambda: slave.write_register(HSPD + 1, 5),
                        lambda: slave.read_coils(SVON, 1)):
                with pytest.raises(ModbusException):
                    await bad()


# -- the promises on this drive: a stop wins, a cancelled caller stops, a refusal sends
# nothing, leaving the machine leaves it at rest (as test_promises.py on the demo) -------


def starts_and_stops(wire: Any, address: int, since: float) -> list[tuple[str, float]]:
    """Its starts (the move or a jog coil forced) and stops (STOPX, ABORTX) after
    ``since``, with the time each began to leave."""
    out = []
    for f in list(wire.log):
        if f.direction != "request" or f.address != address or f.start <= since:
            continue
        pdu = f.data[1:-2]
        if pdu[0] != 5:
            continue
        coil = int.from_bytes(pdu[1:3], "big")
        if coil in (MOVEX, JOG_PLUS, JOG_MINUS):
            out.append(("start", f.start))
        elif coil in (STOPX, ABORTX):
            out.append(("stop", f.start))
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
            frames = starts_and_stops(wire, stopper.config.address, called)
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


async def test_a_move_of_a_disabled_axis_says_to_enable_it() -> None:
    """The servo powers up off (MST 0x0, p. 34): a move is refused before any frame."""
    with anyio.fail_after(30):
        async with open_machine(machine("disabled")) as m:
            a, wire = m.axes["a"], m.wires["l"]
            await a.refresh()
            assert a.state is AxisState.DISABLED
            since = time.monotonic()
            with pytest.raises(DrivebusError, match=r"in state Disabled: enable it first"):
                await a.move_to(10.0)
            assert not [p for p in request_pdus(wire, since) if p[0] in (5, 16)]
