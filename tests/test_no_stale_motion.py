"""Enable, reset and a mode change never start motion (issue 31, item 1).

A drive keeps what it was last told. A CiA 402 drive in profile velocity has no start bit:
in Operation enabled with halt clear it runs at its target velocity (60FFh), so a stop by
halt that leaves 60FFh and the mode in place, then disable and enable (or a fault reset and
enable) starts the old jog again while the axis reports Standstill. The ZLAC8015D's speed
mode follows its target speed register the same way. Judged three ways: the simulated CiA
402 device plays the profile's rule itself (not what the engine sends); every built-in and
shipped description's twin, driven through the public API, stays at rest after enable and
reset; and two independent CiA 402 emulators written from their manuals (the Kinco FD on
Modbus RTU over a pty, the Lexium 32 on Modbus TCP; tests/test_foreign_drives*.py) stay at
rest too.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import anyio
import pytest

from drivebus import AxisState, open_machine
from drivebus.clock import monotonic
from drivebus.drives.cia402 import Controlword, Mode, State
from drivebus.errors import NotSupported
from drivebus.motion import Axis
from drivebus.sim.cia402_device import Cia402Device, Cia402Setup
from pymodbus_servers import PYMODBUS

ROOT = Path(__file__).resolve().parents[1]
DRIVES = ROOT / "configs" / "drives"

SEQUENCES = ("stop-disable", "halt_now-reset", "halt_now-disable", "fault-reset")
"""What ends the jog before the enable: a stop and a disable; an emergency stop and a
reset; an emergency stop and a disable; a drive fault and a reset."""


# -- the CiA 402 device plays what the profile says a drive does with a stale target --------


def _device() -> tuple[Cia402Device, float]:
    """A device in profile velocity running at 10 000 increments/s at t = 1 s."""
    d = Cia402Device(Cia402Setup(), now=0.0)
    for word in (0x06, 0x07, 0x0F):
        d.write("controlword", word, 0.0)
    d.write("modes_of_operation", Mode.PROFILE_VELOCITY, 0.0)
    d.write("target_velocity", 10_000, 0.0)
    assert d.read("velocity_actual_value", 1.0) == 10_000
    return d, 1.0


def test_the_cia402_device_runs_at_a_target_velocity_left_in_it() -> None:
    """Profile velocity has no start bit (CiA 402-2: controlword bits 4-6 reserved in that
    mode): whatever reaches Operation enabled with halt clear runs at 60FFh, and so does
    a change to mode 3; halt set on the way in holds the axis."""
    d, t = _device()
    d.write("controlword", 0x0F | Controlword.HALT, t)  # stop: halt
    t += 1.0
    assert not d.is_moving(t)
    d.write("controlword", 0x06, t)  # disable
    for word in (0x06, 0x07, 0x0F):  # enable
        d.write("controlword", word, t + 0.1)
    assert d.state_at(t + 0.1) is State.OPERATION_ENABLED
    assert d.read("velocity_actual_value", t + 1.1) == 10_000  # the old jog runs again
    d.raise_fault(0x7500, t + 1.1)  # a fault, a fault reset, enable: the same
    t += 2.0
    for word in (0x00, 0x80, 0x06, 0x07, 0x0F):
        d.write("controlword", word, t)
    assert d.read("velocity_actual_value", t + 1.0) == 10_000
    d.write("controlword", 0x06, t + 1.0)
    for word in (0x06, 0x07, 0x0F | Controlword.HALT):  # halt set on the way in: held
        d.write("controlword", word, t + 1.1)
    assert d.state_at(t + 1.1) is State.OPERATION_ENABLED and not d.is_moving(t + 2.0)
    d.write("modes_of_operation", Mode.PROFILE_POSITION, t + 2.0)
    d.write("controlword", 0x0F, t + 2.0)  # halt clear in profile position: nothing
    assert not d.is_moving(t + 2.5)
    d.write("modes_of_operation", Mode.PROFILE_VELOCITY, t + 2.5)  # a mode change runs it
    assert d.read("velocity_actual_value", t + 3.5) == 10_000


# -- every description's twin, through the public API --------------------------------------

# (name, drive, pulses/rev, line settings or "tcp", axis extras, a fault code it clears)
TWINS: list[tuple[str, str, int, str, dict[str, Any], int]] = [
    ("kinco", str(DRIVES / "kinco_fd.toml"), 10000, "115200 8N1", {}, 0x2310),
    ("lexium", str(DRIVES / "lexium32.toml"), 16384, "tcp", {}, 0x3200),
    ("zlac", str(DRIVES / "zlac8015d.toml"), 16384, "115200 8N1", {}, 0x0004),
    ("stf", str(DRIVES / "moons_stf.toml"), 20000, "115200 8N1", {}, 0x0080),
    ("leadshine", str(DRIVES / "leadshine_pr.toml"), 10000, "115200 8N1", {}, 1),
    ("az", str(DRIVES / "oriental_az.toml"), 1000, "115200 8N1", {}, 0x30),
    ("delta", str(DRIVES / "delta_asda_b2.toml"), 100000, "115200 8E1", {}, 0x01),
    ("iai", str(DRIVES / "iai_robo_cylinder.toml"), 1000, "115200 8N1", {}, 0x0E0),
    ("jvl", str(DRIVES / "jvl_mis.toml"), 1600, "115200 8N1", {}, 0x0001),
    ("svx", str(ROOT / "tests/drives/arcus_titan_svx.toml"), 10000, "115200 8N1", {}, 4),
    ("pd4c", str(ROOT / "tests/drives/nanotec_pd4c.toml"), 3600, "115200 8N1", {}, 0x3210),
    ("nt86", "NT86", 4000, "115200 8N1",
     {"drive_options": {"enable_input": 3, "clear_alarm_input": 4}}, 1),
    ("epr60", "EPR60", 4000, "tcp",
     {"drive_options": {"enable_input": 3, "clear_alarm_input": 4}}, 1),
    ("bhss", "BHSS", 1000, "115200 8N1", {}, 4),
    ("cl86r", "CL86R", 1000, "115200 8N1", {}, 1),
]
"""Every description that can run at a speed (the SMC LEC6 cannot: its tests are its
emulator's; the OD2000 has no motion procedures)."""


def twin_machine(name: str, drive: str, ppr: int, settings: str, extra: dict[str, Any],
                 tag: str) -> dict[str, Any]:
    """One axis on a simulated line of its own, without soft limits (a jog is a speed
    run, not a move to a limit)."""
    sim = f"sim://stale-{name}-{tag}"
    line: dict[str, Any] = ({"kind": "tcp", "host": sim, "timeout": 0.2} if settings == "tcp"
                            else {"port": sim, "settings": settings, "timeout": 0.1})
    axis = {"line": "l", "address": 1, "drive": drive, "pulses_per_rev": ppr,
            "units_per_rev": 10.0, "speed": 20.0, "accel": 200.0, "decel": 200.0,
            "poll": {"moving": 0.01, "idle": 0.05}, **extra}
    return {"name": f"stale-{name}", "lines": {"l": line}, "axes": {"a": axis}}


async def until(cond: Callable[[], bool], what: str, timeout: float = 5.0) -> None:
    """Wait (bounded) for a condition on a twin or an emulator."""
    try:
        with anyio.fail_after(timeout):
            while not cond():  # noqa: ASYNC110 - the drive's side has no event to wait on
                await anyio.sleep(0.005)
    except TimeoutError:
        raise AssertionError(f"waited {timeout} s for {what}") from None


async def first_alarm(a: Axis) -> None:
    """Until a status polled by the axis shows the drive's alarm (bounded)."""
    with anyio.fail_after(5):
        async for st in a.watch():
            if st.alarm:
                return


async def end_the_jog(a: Axis, sequence: str, fault: Callable[[], None]) -> None:
    """End a running jog as ``sequence`` says (see SEQUENCES)."""
    if sequence == "stop-disable":
        await a.stop()
        await a.disable()
    elif sequence.startswith("halt_now"):
        await a.halt_now()
        if sequence.endswith("disable"):
            await a.disable()
        else:
            await a.reset()
    else:
        fault()
        await first_alarm(a)
        await a.reset()


@pytest.mark.parametrize("sequence", SEQUENCES)
@pytest.mark.parametrize(("name", "drive", "ppr", "settings", "extra", "code"), TWINS,
                         ids=[t[0] for t in TWINS])
async def test_enable_and_reset_after_a_jog_start_nothing_on_the_twin(
        name: str, drive: str, ppr: int, settings: str, extra: dict[str, Any], code: int,
        sequence: str) -> None:
    """Jog, end it (stop, emergency stop or a drive fault; disable or reset), enable: the
    twin's motor stands, and still stands at the next poll."""
    with anyio.fail_after(30):
        async with open_machine(twin_machine(name, drive, ppr, settings, extra,
                                             sequence)) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            a.profile.check_supported("speed_run")
            if sequence.endswith("disable"):
                a.profile.check_supported("disable")
            try:
                a.profile.check_supported("clear_alarm")
                clears = True
            except NotSupported:
                clears = sequence != "fault-reset"
            await a.enable()
            if not clears:  # the JVL MIS: no documented error clear
                await a.jog(5.0, watchdog=None)
                await until(twin.is_moving, "the jog to run on the twin")
                twin.raise_alarm(code)
                await first_alarm(a)
                with pytest.raises(NotSupported):  # refused: the axis stays in its error
                    await a.reset()
                assert not twin.is_moving() and a.state is AxisState.ERROR_STOP
                return
            await a.jog(5.0, watchdog=None)
            await until(twin.is_moving, "the jog to run on the twin")
            await end_the_jog(a, sequence, lambda: twin.raise_alarm(code))
            assert not twin.is_moving()
            at = twin.position()
            await a.enable()
            assert not twin.is_moving(), f"{name}: enable after {sequence} started the motor"
            st = await a.refresh()
            assert not twin.is_moving() and twin.position() == at
            assert not st.moving and a.state is AxisState.STANDSTILL


@pytest.mark.parametrize(("name", "drive", "ppr", "settings", "extra", "code"), TWINS,
                         ids=[t[0] for t in TWINS])
async def test_a_jog_after_a_fault_ended_one_never_runs_the_old_one_first(
        name: str, drive: str, ppr: int, settings: str, extra: dict[str, Any],
        code: int) -> None:
    """A drive fault ends a jog (the drive stops itself: no stop is sent, its target
    speed stays), reset, then a jog the other way: the motor never runs the old direction
    on the way (the ZLAC8015D changed to speed mode before it wrote the new speed, and
    ran the stale one first)."""
    with anyio.fail_after(30):
        async with open_machine(twin_machine(name, drive, ppr, settings, extra,
                                             "refault")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            a.profile.check_supported("speed_run")
            try:
                a.profile.check_supported("clear_alarm")
            except NotSupported:
                pytest.skip(f"{name}: no documented error clear (its own test covers it)")
            await a.enable()
            await a.jog(5.0, watchdog=None)
            await until(twin.is_moving, "the jog to run on the twin")
            twin.raise_alarm(code)
            await first_alarm(a)
            await a.reset()
            await a.enable()
            assert not twin.is_moving()
            t0 = monotonic()
            await a.jog(-5.0, watchdog=None)
            await until(twin.is_moving, "the jog the other way to run on the twin")
            await a.stop()
            forward = [seg for seg in twin.kin.trace(t0, monotonic())
                       if seg.v0 > 0 or seg.at(seg.t1)[1] > 0]
            assert not forward, f"{name}: ran the old jog's direction: {forward}"


@pytest.mark.parametrize("name", ["kinco", "lexium", "zlac"])
async def test_a_stopped_speed_run_leaves_no_target_speed(name: str) -> None:
    """A stop and an emergency stop of a speed run leave target velocity (60FFh; the
    ZLAC8015D's 0x2088) at 0, written after the stop itself: nothing is left for a later
    enable or a change to speed mode to start."""
    spec = next(t for t in TWINS if t[0] == name)
    with anyio.fail_after(30):
        async with open_machine(twin_machine(*spec[:5], tag="target")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            wire: Any = m.wires["l"]
            d = twin.description
            device = getattr(twin, "device", None)  # the CiA 402 twins' device
            reg = d.objects["target_velocity"] if device is not None else d.regs["speed_cmd"]
            address = reg.register.address

            def target() -> int:
                return int(device.values["target_velocity"] if device is not None
                           else twin.regs[address])

            await a.enable()
            for stop in (a.stop, a.halt_now):
                await a.enable()
                await a.jog(-5.0, watchdog=None)
                await until(twin.is_moving, "the jog to run on the twin")
                assert target() != 0
                since = len(wire.log)
                await stop()
                assert target() == 0, f"{stop.__name__} left a target speed"
                if device is not None:  # the halt or quick stop first, then 60FFh
                    writes = written(wire, since)
                    control = d.objects["controlword"].register.address
                    assert control in writes[0] and any(address in w for w in writes[1:])


def written(wire: Any, since: int = 0) -> list[range]:
    """The registers each FC06/FC16 request on a simulated wire wrote, in wire order, from
    log index ``since`` (RTU frames, or the requests of a simulated Modbus TCP server)."""
    out = []
    for f in list(wire.log)[since:]:
        pdu = getattr(f, "pdu", None)
        if pdu is None:
            if f.direction != "request":
                continue
            pdu = f.data[1:-2]
        if pdu and pdu[0] in (6, 16):
            start = int.from_bytes(pdu[1:3], "big")
            out.append(range(start, start + (1 if pdu[0] == 6 else
                                             int.from_bytes(pdu[3:5], "big"))))
    return out


async def test_a_speed_run_writes_its_target_before_it_changes_the_mode() -> None:
    """On a CiA 402 drive in profile position with halt clear (after a move) and a target
    velocity left in it by another tool, the change to profile velocity would run at that
    one: the jog writes its own target velocity first."""
    with anyio.fail_after(30):
        async with open_machine(twin_machine(*TWINS[0][:5], tag="mode")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            wire: Any = m.wires["l"]
            await a.enable()
            await a.move_by(2.0)
            twin.device.write("target_velocity", -50_000, monotonic())  # someone else's value
            wire.clear_log()
            await a.jog(5.0, watchdog=None)
            await until(twin.is_moving, "the jog to run on the twin")
            objects = twin.description.objects
            mode = objects["modes_of_operation"].register.address
            velocity = objects["target_velocity"].register.address
            order = [r for w in written(wire) for r in (mode, velocity) if r in w]
            assert order[:2] == [velocity, mode], order
            assert twin.velocity() > 0
            await a.stop()


# -- independent emulators (pymodbus, written from the manuals) ------------------------------

emulated = pytest.mark.skipif(PYMODBUS < (3, 13), reason="SimDevice actions: pymodbus 3.13+")


def emulated_machine(line: dict[str, Any], drive: Path, ppr: int) -> dict[str, Any]:
    axis = {"line": "bus", "address": 1, "drive": str(drive), "pulses_per_rev": ppr,
            "units_per_rev": 10.0, "unit": "mm", "speed": 30.0, "accel": 300.0,
            "decel": 300.0, "poll": {"moving": 0.01, "idle": 0.05}}
    return {"name": "stale-emulated", "lines": {"bus": line}, "axes": {"a": axis}}


@emulated
async def test_enable_and_reset_after_a_jog_start_nothing_on_the_kinco_emulator() -> None:
    from test_foreign_drives import K_READ_ONLY, K_TARGET_VEL, Kinco, served

    drive = Kinco()
    with anyio.fail_after(60):
        async with served(drive, K_READ_ONLY) as line, \
                open_machine(emulated_machine(line, DRIVES / "kinco_fd.toml", 10000)) as m:
            a = m.axes["a"]
            for sequence in SEQUENCES:
                await a.enable()
                await a.jog(5.0, watchdog=None)
                await until(lambda: drive.vel > 0, "the jog to run on the emulator")
                await end_the_jog(a, sequence, drive.raise_fault)
                await until(lambda: drive.motion is None, "the emulator to stop")
                await a.enable()
                assert drive.state == "enabled" and drive.motion is None, sequence
                await a.refresh()
                assert drive.motion is None and drive.vel == 0, sequence
                assert drive.s32(K_TARGET_VEL) == 0, sequence


@emulated
async def test_enable_and_reset_after_a_jog_start_nothing_on_the_lexium_emulator() -> None:
    from test_foreign_drives import served
    from test_foreign_drives_more import L_PV_TARGET, L_READ_ONLY, Lexium32

    lx = Lexium32()
    with anyio.fail_after(60):
        async with served(lx, L_READ_ONLY, "tcp") as line, \
                open_machine(emulated_machine(line, DRIVES / "lexium32.toml", 16384)) as m:
            a = m.axes["a"]
            for sequence in SEQUENCES:
                await a.enable()
                await a.jog(5.0, watchdog=None)
                await until(lambda: lx.vel > 0, "the jog to run on the emulator")
                await end_the_jog(a, sequence, lambda: lx.fault(0x3200))
                await until(lambda: not lx.moving, "the emulator to stop")
                await a.enable()
                assert lx.state == "operation_enabled" and not lx.moving, sequence
                await a.refresh()
                assert not lx.moving and lx.vel == 0, sequence
                assert lx.get(L_PV_TARGET) == 0, sequence


async def test_a_zlac_move_that_arrived_is_not_taken_for_motion_after_a_power_cycle() -> None:
    """The ZLAC8015D has no moving bit for a position move: its description remembered
    the move against the position counter, and a power cycle's zeroed counter read as
    motion for good (the axis in DiscreteMotion, every command refused)."""
    with anyio.fail_after(30):
        async with open_machine(twin_machine(*TWINS[2][:5], tag="power")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            await a.enable()
            await a.move_by(1.0)
            assert twin.position() != 0
            twin.power_cycle()
            async for st in a.watch():  # a status polled after it: the counter at 0
                if st.position == 0:
                    break
            st = await a.refresh()
            assert not st.moving and not twin.is_moving()
            assert a.state is not AxisState.DISCRETE_MOTION


@pytest.mark.parametrize("how", ["answered at once", "offline a while"])
async def test_a_zlac_is_enabled_again_after_a_power_cycle(how: str) -> None:
    """The ZLAC8015D reports no enable: its description tracks what it last commanded. A
    power cycle left it "enabled", so enable() sent nothing and the next move timed out on
    a drive that had come back released. A restart (the counter moved at rest, or the
    drive did not answer a while) leaves the axis Disabled, and enable() enables it."""
    with anyio.fail_after(30):
        async with open_machine(twin_machine(*TWINS[2][:5], tag=f"cycle-{how}")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            await a.enable()
            if how == "answered at once":
                await a.move_by(1.0)
                assert twin.position() != 0
                twin.power_cycle()
            else:  # at 0 throughout: only the silence says it may have restarted
                twin.power_loss()
                async for _ in a.watch():
                    if a.state is AxisState.OFFLINE:
                        break
                twin.power_restore()
            assert not twin.enabled
            async for st in a.watch():  # a status polled after the power came back
                if a.state is not AxisState.OFFLINE and st.position == 0:
                    break
            assert a.state is AxisState.DISABLED and not a.status.enabled
            await a.enable()
            assert twin.enabled
            await a.move_by(1.0)
            assert twin.position() == a.units.to_pulses(1.0) and not twin.is_moving()


async def test_a_jvl_in_error_is_not_taken_for_moving_once_enabled() -> None:
    """The JVL MIS has no documented error clear: after an alarm during a jog, enable()
    put it back in position mode with its in-position bit clear, which its description
    read as motion for good (the twin at rest; disable() waited 30 s for a timeout)."""
    name, drive, ppr, settings, extra, code = next(t for t in TWINS if t[0] == "jvl")
    with anyio.fail_after(30):
        async with open_machine(twin_machine(name, drive, ppr, settings, extra,
                                             "error")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            await a.enable()
            await a.jog(5.0, watchdog=None)
            await until(twin.is_moving, "the jog to run on the twin")
            twin.raise_alarm(code)
            await first_alarm(a)
            await until(lambda: not twin.is_moving(), "the drive to stop on its fault")
            await a.enable()
            st = await a.refresh()
            assert not st.moving and not twin.is_moving()
            with anyio.fail_after(5):  # at rest: nothing to wait for
                await a.disable()
