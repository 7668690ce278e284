"""Issue 5 end to end: the EPR60 over Modbus TCP, mixed and RTU-over-TCP machines, peer drops.

Everything runs on loopback with real sockets: ``SimTcpServer`` / ``SimSerialServer`` serve
the drive twins, ``TcpLine`` / ``RtuOverTcpLine`` talk to them under the usual ``Bus``.

The EPR60 manual has no MBAP frame at all (its examples are RTU); the expected TCP frames
below are the extraction's "[derived]" ones (shared/drives/002_epr60_tcp.md §6), which
are the manual's register writes in standard MBAP framing (transaction id 1, unit 1), and
the RTU frames are the manual's verbatim (CRC checked) or tests/test_drive_epr60.py's.
"""

from __future__ import annotations

import contextlib
import struct
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from typing import Any

import anyio
import anyio.abc
import pytest
from anyio.abc import SocketAttribute

from drivebus import AxisState, Bus, LineSettings, open_machine
from drivebus.config import MachineConfig, parse_config
from drivebus.drives.base import MoveParams
from drivebus.drives.nt_family import EPR60Profile
from drivebus.errors import DriveOffline
from drivebus.line.rtu import crc_ok
from drivebus.line.tcp import TcpLine
from drivebus.motion import Machine
from drivebus.sim import VirtualWire, sim_bus
from drivebus.sim.drive import TwinSetup
from drivebus.sim.drives.nt_family import SimEPR60
from drivebus.sim.tcp import SimSerialServer, SimTcpServer
from nt_helpers import idle, wait_for
from ports import reserved_port

HOST = "127.0.0.1"
FAST = LineSettings.parse("115200 8N1")
QUICK = MoveParams(speed_rpm=3000, accel_rps2=1000, decel_rps2=1000)
MANUAL = MoveParams(speed_rpm=600, accel_rps2=200, decel_rps2=200)
"""The parameters of the extraction's move examples (§6.1/6.2)."""
STATUS_POLL = bytes.fromhex("03 0000 000B")
"""The EPR60 profile's status read (registers 0-10): polls, filtered out of comparisons."""
_MBAP = struct.Struct(">HHHB")


def rtu_pdu(frame_hex: str) -> bytes:
    """The PDU inside an RTU frame for slave 1 (checked: address 1, valid CRC)."""
    adu = bytes.fromhex(frame_hex)
    assert adu[0] == 1 and crc_ok(adu), frame_hex
    return adu[1:-2]


def split_mbap(stream: bytes) -> list[bytes]:
    """Cut a client's byte stream into ADUs, checking each MBAP header on the way."""
    out = []
    while stream:
        assert len(stream) >= _MBAP.size, stream.hex(" ")
        _tid, pid, length, _unit = _MBAP.unpack_from(stream)
        assert pid == 0, f"protocol id {pid}"
        assert 2 <= length <= 254 and len(stream) >= 6 + length, stream.hex(" ")
        out.append(stream[: 6 + length])
        stream = stream[6 + length :]
    return out


def as_tid_1(adu: bytes) -> str:
    """``adu`` in hex with transaction id 1, to compare with the extraction's examples."""
    return (b"\x00\x01" + adu[2:]).hex(" ").upper()


# -- a raw-byte tap between the TCP line and the server ----------------------------------------


@dataclass
class Tap:
    """A loopback TCP relay's port and the raw bytes its clients sent through it."""

    port: int = 0
    sent: bytearray = field(default_factory=bytearray)


@asynccontextmanager
async def tap(target: int) -> AsyncIterator[Tap]:
    """Relay every connection to ``target`` on loopback and record the client's bytes."""
    rec = Tap()

    async def pump(src: anyio.abc.ByteStream, dst: anyio.abc.ByteStream, record: bool) -> None:
        with contextlib.suppress(anyio.BrokenResourceError, anyio.ClosedResourceError):
            async for chunk in src:
                if record:
                    rec.sent.extend(chunk)
                await dst.send(chunk)

    async def relay(client: anyio.abc.SocketStream) -> None:
        server = await anyio.connect_tcp(HOST, target)
        async with client, server, anyio.create_task_group() as tg:
            tg.start_soon(pump, client, server, True)
            tg.start_soon(pump, server, client, False)

    failure: Exception | None = None
    listener = await anyio.create_tcp_listener(local_host=HOST)
    async with listener, anyio.create_task_group() as tg:
        rec.port = listener.extra(SocketAttribute.local_port)
        tg.start_soon(listener.serve, relay)
        try:
            yield rec
        except Exception as exc:  # re-raised below as it is, not wrapped in a group
            failure = exc
        tg.cancel_scope.cancel()
    if failure is not None:
        raise failure


# -- one EPR60 on either transport -------------------------------------------------------------


@dataclass
class Rig:
    """A set-up EPR60 profile, its twin, and what its server received since ``clear()``."""

    profile: EPR60Profile
    sim: SimEPR60
    requests: Callable[[], list[tuple[int, bytes]]]
    """(unit, PDU) of each request, as the server saw it."""
    clear: Callable[[], None]
    raw: Callable[[], list[bytes]] = list
    """The raw ADUs on the socket (Modbus TCP only)."""
    received: Callable[[], list[float]] = list
    """When the server received each request since ``clear()``: the twin acts on a
    request at that time (Modbus TCP only)."""

    def pdus(self) -> list[bytes]:
        """PDUs received since the last ``clear``, every one checked to be for unit 1."""
        reqs = self.requests()
        assert {unit for unit, _ in reqs} <= {1}
        return [pdu for _, pdu in reqs]

    def commands(self) -> list[bytes]:
        """Received PDUs without the status polls (their number depends on timing)."""
        return [p for p in self.pdus() if p != STATUS_POLL]

    def sent_adus(self) -> list[str]:
        """The raw ADUs without the status polls, as ``as_tid_1`` hex."""
        return [as_tid_1(a) for a in self.raw() if a[7:] != STATUS_POLL]


@asynccontextmanager
async def over_tcp(sim: SimEPR60 | None = None, **opts: Any) -> AsyncIterator[Rig]:
    """The twin behind a ``SimTcpServer``, reached through a tap by a ``TcpLine``."""
    sim = sim or SimEPR60(1)
    async with (
        SimTcpServer([sim]) as srv,
        tap(srv.port) as t,
        Bus(TcpLine(HOST, t.port), timeout=0.5) as bus,
    ):
        profile = EPR60Profile(bus.slave(1), **opts)
        await profile.setup()
        mark = 0

        def clear() -> None:
            nonlocal mark
            srv.log.clear()
            mark = len(t.sent)

        def raw() -> list[bytes]:
            adus = split_mbap(bytes(t.sent[mark:]))
            assert [a[7:] for a in adus] == [r.pdu for r in srv.log]  # nothing lost, no extra
            assert [a[:2] for a in adus] == [r.tid.to_bytes(2, "big") for r in srv.log]
            return adus

        clear()
        yield Rig(profile, sim, lambda: [(r.unit, r.pdu) for r in srv.log], clear, raw,
                  lambda: [r.received for r in srv.log])


@asynccontextmanager
async def over_rtu(sim: SimEPR60 | None = None, **opts: Any) -> AsyncIterator[Rig]:
    """The twin on the RTU sim wire at 115200 8N1 (how tests/test_drive_epr60.py runs it)."""
    sim = sim or SimEPR60(1)
    async with sim_bus([sim], FAST) as (wire, bus):
        profile = EPR60Profile(bus.slave(1), **opts)
        await profile.setup()
        wire.clear_log()

        def requests() -> list[tuple[int, bytes]]:
            frames = wire.requests()
            assert all(crc_ok(f.data) for f in frames)
            return [(f.address, f.data[1:-2]) for f in frames]

        yield Rig(profile, sim, requests, wire.clear_log)


# -- waiting -----------------------------------------------------------------------------------


# == 1. the manual's operations on the EPR60 over Modbus TCP ===================================


async def test_tcp_relative_and_absolute_moves_in_the_manuals_frames() -> None:
    async with over_tcp() as rig:
        p = rig.profile
        await p.move_relative(2000, MANUAL)
        assert rig.sent_adus()[-2:] == [  # §6.1: 70-74 (2000 forward), then 18=1
            "00 01 00 00 00 11 01 10 00 46 00 05 0A 00 C8 00 C8 02 58 07 D0 00 00",
            "00 01 00 00 00 06 01 06 00 12 00 01",
        ]
        st = await wait_for(p, idle)
        assert st.position == 2000 == rig.sim.position() and st.in_position
        rig.clear()
        await p.move_absolute(-4000, MANUAL)
        assert rig.sent_adus() == [  # §6.2: 84=1, target -4000 low word first, 18=1
            "00 01 00 00 00 06 01 06 00 54 00 01",
            "00 01 00 00 00 11 01 10 00 46 00 05 0A 00 C8 00 C8 02 58 F0 60 FF FF",
            "00 01 00 00 00 06 01 06 00 12 00 01",
        ]
        assert (await wait_for(p, idle)).position == -4000 == rig.sim.position()
        rig.clear()
        await p.move_relative(-1000, QUICK)
        assert rig.sent_adus()[-1] == "00 01 00 00 00 06 01 06 00 12 00 02"  # 18=2 reverse
        assert (await wait_for(p, idle)).position == -5000 == rig.sim.position()


async def test_tcp_speed_run_speed_change_and_emergency_stop() -> None:
    async with over_tcp() as rig:
        p = rig.profile
        await p.speed_run(600, 100, 100)
        assert rig.sent_adus()[-2:] == [  # §6.3: the manual's 75-78 block, then 18=3
            "00 01 00 00 00 0F 01 10 00 4B 00 04 08 00 64 00 64 02 58 01 F4",
            "00 01 00 00 00 06 01 06 00 12 00 03",
        ]
        assert rig.commands()[-2:] == [  # the very PDUs of the manual's RTU frames
            rtu_pdu("01 10 00 4B 00 04 08 00 64 00 64 02 58 01 F4 86 EC"),
            rtu_pdu("01 06 00 12 00 03 69 CE"),
        ]
        await wait_for(p, lambda s: s.velocity_rpm == 600)
        rig.clear()
        await p.speed_run(300, 100, 100)  # same direction: 77 only, it applies at once
        assert rig.sent_adus() == [
            "00 01 00 00 00 06 01 03 00 01 00 01",  # MOV check (register 1)
            "00 01 00 00 00 06 01 06 00 4D 01 2C",  # §6.3: 77 = 300
        ]
        st = await wait_for(p, lambda s: s.velocity_rpm == 300)
        assert st.moving and rig.sim.is_moving()
        rig.clear()
        await p.emergency_stop()
        assert rig.sent_adus() == ["00 01 00 00 00 06 01 06 00 12 00 05"]  # §6.5
        st = await wait_for(p, idle)
        assert st.velocity_rpm == 0 and not rig.sim.is_moving()


async def test_tcp_decelerating_stop_uses_the_run_deceleration() -> None:
    async with over_tcp() as rig:
        p = rig.profile
        # 600 rpm at 4000 pulses/rev = 40000 pulses/s; decel 20 rev/s² = 80000 pulses/s²:
        # a decelerating stop takes 0.5 s and 10000 pulses (an e-stop at 500 rev/s²: 400).
        await p.speed_run(600, 100, 20)
        await wait_for(p, lambda s: s.velocity_rpm == 600)
        rig.clear()
        await p.stop()
        assert rig.sent_adus() == ["00 01 00 00 00 06 01 06 00 12 00 06"]  # §6.4: 18=6
        # where the twin was when the stop reached it (not when this task ran again: on a
        # busy machine that is later, part of the ramp down already behind)
        at_stop = rig.sim.position(rig.received()[0])
        st = await wait_for(p, lambda s: s.velocity_rpm is not None and s.velocity_rpm < 600)
        assert st.moving and st.velocity_rpm is not None and st.velocity_rpm > 0  # ramping
        st = await wait_for(p, idle)
        assert st.position == rig.sim.position()
        assert st.position is not None
        assert st.position - at_stop == pytest.approx(10000, rel=0.1)


async def test_tcp_homing_on_the_negative_limit_with_the_default_parameters() -> None:
    sim = SimEPR60(1, setup=TwinSetup(limit_negative=-6000))
    async with over_tcp(sim, home_input=5) as rig:
        p = rig.profile
        await p.home("limit_negative", speed_rpm=200, creep_rpm=40, accel_rps2=100, offset=100)
        assert rig.sent_adus() == [
            # §6.6: 79-83 = method 0 (negative limit), 200 rpm, 40 rpm, 100 rev/s², 100
            "00 01 00 00 00 11 01 10 00 4F 00 05 0A 00 00 00 C8 00 28 00 64 00 64",
            "00 01 00 00 00 06 01 06 00 14 00 01",  # 20=1 homing mode
            "00 01 00 00 00 06 01 03 00 01 00 01",  # status: HOME before the start
            "00 01 00 00 00 06 01 03 00 40 00 01",  # IN5's setting (function 12)
            "00 01 00 00 00 06 01 06 00 40 00 2C",  # polarity flipped: start homing
            "00 01 00 00 00 06 01 06 00 40 00 0C",  # and back
        ]
        assert rig.commands()[1:] == [rtu_pdu(f) for f in (  # as over RTU
            "01 06 00 14 00 01 08 0E", "01 03 00 01 00 01 D5 CA", "01 03 00 40 00 01 85 DE",
            "01 06 00 40 00 2C 89 C3", "01 06 00 40 00 0C 88 1B",
        )]
        st = await wait_for(p, lambda s: not s.homing)
        assert st.homed and not st.moving and st.in_position and st.position == 0
        assert sim.physical_position() == -6000 + 100  # 100 pulses off the limit's edge
        rig.clear()
        await p.move_relative(500, QUICK)  # register 18 acts only in mode 20=0
        assert rig.sent_adus()[-2] == "00 01 00 00 00 06 01 06 00 14 00 00"
        assert (await wait_for(p, idle)).position == 500


async def test_tcp_alarm_raised_and_cleared() -> None:
    async with over_tcp(enable_input=3, clear_alarm_input=4) as rig:
        p = rig.profile
        rig.sim.raise_alarm(0x10)
        st = await p.read_status()
        assert st.alarm and st.alarm_code == 0x10 and st.alarm_text == "OT: over-temperature"
        rig.clear()
        await p.clear_alarm()
        assert rig.sent_adus() == [  # IN4 (register 63) pulsed, then registers 0-1 read
            "00 01 00 00 00 06 01 03 00 3F 00 01",
            "00 01 00 00 00 06 01 06 00 3F 00 25",
            "00 01 00 00 00 06 01 06 00 3F 00 05",
            "00 01 00 00 00 06 01 03 00 00 00 02",
        ]
        st = await p.read_status()
        assert not st.alarm
        ident = await p.read_identity()
        assert ident.family == "EPR60" and ident.raw["drive_id"] == 60


FAST_HOMING = {"speed_rpm": 600, "creep_rpm": 200, "accel_rps2": 1000}


async def manual_script(rig: Rig) -> None:
    """Every manual operation in a row: moves, runs, both stops, homing, alarm."""
    p = rig.profile
    await p.move_relative(-7000, QUICK)
    await wait_for(p, idle)
    await p.move_absolute(1500, QUICK)
    assert (await wait_for(p, idle)).position == 1500
    await p.speed_run(600, 100, 100)
    await wait_for(p, lambda s: s.velocity_rpm == 600)
    await p.speed_run(300, 100, 100)
    await wait_for(p, lambda s: s.velocity_rpm == 300)
    await p.stop()
    await wait_for(p, idle)
    await p.speed_run(-600, 1000, 1000)
    await wait_for(p, lambda s: s.velocity_rpm == -600)
    await p.emergency_stop()
    await wait_for(p, idle)
    await p.home("limit_negative", offset=100, **FAST_HOMING)
    assert (await wait_for(p, lambda s: not s.homing)).homed
    rig.sim.raise_alarm(0x10)
    assert (await p.read_status()).alarm
    await p.clear_alarm()
    assert not (await p.read_status()).alarm


async def test_tcp_sends_the_same_pdus_as_rtu_in_mbap_frames_for_unit_1() -> None:
    opts: dict[str, Any] = {"home_input": 5, "clear_alarm_input": 4}
    async with over_rtu(SimEPR60(1, setup=TwinSetup(limit_negative=-8000)), **opts) as rig:
        await manual_script(rig)
        over_rs485 = rig.commands()
    async with over_tcp(SimEPR60(1, setup=TwinSetup(limit_negative=-8000)), **opts) as rig:
        await manual_script(rig)
        over_network = rig.commands()
        adus = rig.raw()  # checked against the server's log: same PDUs, same tids
    assert over_network == over_rs485 and len(over_rs485) > 20
    # On the socket: MBAP headers (protocol 0, length = unit + PDU), all for unit 1, with
    # one transaction id after another (one request in flight at a time).
    assert {a[6] for a in adus} == {1}
    assert all(int.from_bytes(a[4:6], "big") == len(a) - 6 for a in adus)
    tids = [int.from_bytes(a[:2], "big") for a in adus]
    assert tids == list(range(tids[0], tids[0] + len(tids)))


# == 2..4: machines ============================================================================


def axis(line: str, address: int, drive: str, **kw: Any) -> dict[str, Any]:
    """An axis of 10 units per rev, 1000 pulses/rev, fast defaults and fast polls."""
    return {
        "line": line, "address": address, "drive": drive, "pulses_per_rev": 1000,
        "units_per_rev": 10.0, "speed": 100.0, "accel": 1000.0, "decel": 1000.0,
        "limits": [-500.0, 500.0], "poll": {"moving": 0.01, "idle": 0.05}, **kw,
    }


def config(lines: dict[str, Any], axes: dict[str, Any]) -> MachineConfig:
    """A validated machine config built in the test."""
    return parse_config({"name": "tcp-test", "lines": lines, "axes": axes})


async def settle(m: Machine, *names: str) -> None:
    """Wait (bounded) until the named axes' actors report a status at rest."""
    with anyio.fail_after(5):
        for n in names:
            async for st in m.axes[n].watch():
                if not st.moving and m.axes[n].state is AxisState.STANDSTILL:
                    break


async def test_mixed_machine_group_move_across_rs485_and_tcp() -> None:
    cfg = config(
        {
            "rs485": {"port": "sim://tcpmix-rs485", "settings": "115200 8N1", "timeout": 0.05},
            "eth": {"kind": "tcp", "host": "sim://tcpmix-eth", "timeout": 0.2},
        },
        {
            "x": axis("rs485", 2, "NT86", settings="115200 8N1"),
            "z": axis("rs485", 3, "CL86R", settings="38400 8N2"),
            "r": axis("eth", 1, "EPR60"),
        },
    )
    with anyio.fail_after(20):
        async with open_machine(cfg) as m:
            wire, srv = m.wires["rs485"], m.wires["eth"]
            assert isinstance(wire, VirtualWire) and isinstance(srv, SimTcpServer)
            assert isinstance(m.buses["eth"].line, TcpLine)
            wire.clear_log()
            report = await m.group("x", "z", "r").move_to({"x": 40.0, "z": -15.0, "r": 25.0})
            assert [m.sim_drives[n].position() for n in ("x", "z", "r")] == [4000, -1500, 2500]
            assert not any(s.is_moving() for s in m.sim_drives.values())
            assert all(m.axes[n].state is AxisState.STANDSTILL for n in ("x", "z", "r"))
            starts = [m.axes[n].command_started_at for n in ("x", "z", "r")]
            assert report.start_skew == pytest.approx(max(starts) - min(starts))
            assert 0 <= report.start_skew < report.duration
            assert report.plans["z"].speed < report.plans["x"].speed  # slowed to match
            # Both RS-485 drives were addressed at their own settings, with no short gap.
            seen = {(f.address, str(f.settings)) for f in wire.requests()}
            assert {(2, "115200 8N1"), (3, "38400 8N2")} <= seen
            assert wire.violations == 0 and not [f for f in wire.log if f.violation]
            assert srv.log and {r.unit for r in srv.log} == {1}


@pytest.mark.serial  # no frame note at a 50 ms timeout: a stall of a loaded CPU makes one
async def test_rtu_over_tcp_machine_moves_nt86_and_cl86r() -> None:
    cfg = config(
        {"ser": {"kind": "rtu-over-tcp", "host": "sim://tcpmix-ser", "settings": "115200 8N1",
                 "timeout": 0.05}},
        {"a": axis("ser", 1, "NT86"), "b": axis("ser", 2, "CL86R")},
    )
    with anyio.fail_after(20):
        async with open_machine(cfg) as m:
            srv = m.wires["ser"]
            assert isinstance(srv, SimSerialServer)
            a, b = m.axes["a"], m.axes["b"]
            await a.move_to(12.5)
            await b.move_by(-7.5)
            assert m.sim_drives["a"].position() == 1250
            assert m.sim_drives["b"].position() == -750
            async with anyio.create_task_group() as tg:  # both at once on the one port
                tg.start_soon(a.move_to, -20.0)
                tg.start_soon(b.move_to, 30.0)
            assert m.sim_drives["a"].position() == -2000
            assert m.sim_drives["b"].position() == 3000
            await m.group("a", "b").move_to({"a": 5.0, "b": -5.0})
            assert [m.sim_drives[n].position() for n in "ab"] == [500, -500]
            assert a.state is b.state is AxisState.STANDSTILL
            requests = srv.requests()
            assert {f.address for f in requests} == {1, 2}
            assert all(crc_ok(f.data) for f in srv.log)
            assert srv.violations == 0 and not [f for f in srv.log if f.note]


# -- 4. the peer closes the connection while an axis moves -------------------------------------


def tcp_machine(host: str, *, retries: int = 2, offline_after: int = 3,
                tcp_port: int = 502) -> MachineConfig:
    """One EPR60 axis on a Modbus TCP line (``sim://NAME`` or a real host:tcp_port)."""
    return config(
        {"eth": {"kind": "tcp", "host": host, "tcp_port": tcp_port, "timeout": 0.2,
                 "retries": retries}},
        {"r": axis("eth", 1, "EPR60", speed=40.0,
                   poll={"moving": 0.01, "idle": 0.05, "offline_after": offline_after})},
    )


async def when_moving(m: Machine, name: str, action: Callable[[], Any]) -> None:
    """Run ``action`` once the axis's actor has polled its drive moving."""
    async for st in m.axes[name].watch():
        if st.moving:
            action()
            return


async def test_peer_close_mid_poll_is_retried_on_a_new_connection() -> None:
    """Documented (line/tcp.py): a dropped connection fails its transaction with
    ConnectionLost, reads are retried and reconnect at once; so the axis never notices."""
    with anyio.fail_after(15):
        async with open_machine(tcp_machine("sim://tcpdrop-retry")) as m:
            srv, line = m.wires["eth"], m.buses["eth"].line
            assert isinstance(srv, SimTcpServer) and isinstance(line, TcpLine)
            x = m.axes["r"]
            async with anyio.create_task_group() as tg:
                tg.start_soon(when_moving, m, "r", srv.drop_next)  # the next poll is dropped
                await x.move_to(20.0)
            assert m.sim_drives["r"].position() == 2000
            assert x.state is AxisState.STANDSTILL and x.error is None
            st = m.buses["eth"].stats.slave(1)
            assert st.connection_errors == 1 and st.retries == 1
            assert srv.accepted == 2 and line.stats.disconnects == 1
            assert line.stats.connects == 2 and line.connected
            assert "connection dropped" in [r.note for r in srv.log]


@pytest.mark.parametrize("drops", [2, 3], ids=["below-offline_after", "reaches-offline_after"])
async def test_repeated_peer_closes_make_the_axis_offline_after_n_failed_polls(
    drops: int,
) -> None:
    """Without retries each dropped connection is one failed poll: ``offline_after`` (3) of
    them in a row make the axis Offline and its move raises; fewer are ridden out. Either
    way the next poll reconnects and the axis is back."""
    cfg = tcp_machine(f"sim://tcpdrop-{drops}", retries=0, offline_after=3)
    with anyio.fail_after(15):
        async with open_machine(cfg) as m:
            srv, line = m.wires["eth"], m.buses["eth"].line
            assert isinstance(srv, SimTcpServer) and isinstance(line, TcpLine)
            x, twin = m.axes["r"], m.sim_drives["r"]
            async with anyio.create_task_group() as tg:
                tg.start_soon(when_moving, m, "r", lambda: srv.drop_next(drops))
                if drops < 3:
                    await x.move_to(20.0)
                else:
                    with pytest.raises(DriveOffline, match=r"stopped answering.*lost"):
                        await x.move_to(20.0)
                    assert x.state is AxisState.OFFLINE
            assert m.buses["eth"].stats.slave(1).connection_errors == drops
            assert line.stats.disconnects == drops
            await settle(m, "r")  # the poll after the drops reconnects: back from Offline
            assert x.error is None and line.connected
            assert srv.accepted == 1 + drops and line.stats.connects == 1 + drops
            # Back from Offline: if it was still moving, nobody's command was waiting on it
            # any more, so the actor stopped it; either way it is at rest, not past 2000.
            assert not twin.is_moving() and twin.position() <= 2000
            await x.move_to(-5.0)
            assert twin.position() == -500


@dataclass
class ServerRun:
    """A ``SimTcpServer`` run by its own task, so that a test can stop it while the
    machine's connection to it stays open (the peer goes away, as a real device would)."""

    server: SimTcpServer
    stop: anyio.Event = field(default_factory=anyio.Event)
    stopped: anyio.Event = field(default_factory=anyio.Event)

    async def close(self) -> None:
        """Drop the connections, stop listening, and wait until the server has ended."""
        self.stop.set()
        await self.stopped.wait()


async def start_server(tg: anyio.abc.TaskGroup, twin: SimEPR60, port: int = 0) -> ServerRun:
    """Start serving ``twin`` on ``port`` (0: any) in a task of ``tg``."""

    async def serve(*, task_status: anyio.abc.TaskStatus[ServerRun]) -> None:
        run: ServerRun | None = None
        try:
            async with SimTcpServer([twin], port=port) as srv:
                run = ServerRun(srv)
                task_status.started(run)
                await run.stop.wait()
        finally:
            if run is not None:
                run.stopped.set()

    return await tg.start(serve)  # type: ignore[no-any-return]


async def test_server_gone_makes_the_axis_offline_and_it_reconnects_when_back() -> None:
    """The peer closes and stops listening mid-move: polls fail (connect refused, backoff),
    the axis goes Offline; when a server listens again on the port the line reconnects."""
    twin = SimEPR60(1)
    # the port stays the server's while it is gone, nobody else's (tests/ports.py)
    with anyio.fail_after(20), reserved_port(HOST) as port:
        async with anyio.create_task_group() as servers:
            first = await start_server(servers, twin, port)
            async with open_machine(tcp_machine(HOST, tcp_port=port)) as m:
                x, line = m.axes["r"], m.buses["eth"].line
                assert isinstance(line, TcpLine) and not m.sim_drives

                async def mover() -> None:
                    with pytest.raises(DriveOffline, match="stopped answering"):
                        await x.move_to(30.0)

                async with anyio.create_task_group() as tg:
                    tg.start_soon(mover)
                    async for st in x.watch():
                        if st.moving:
                            break
                    await first.close()  # connection dropped, listener closed
                assert x.state is AxisState.OFFLINE and not line.connected
                assert line.stats.failed_connects >= 1 and twin.is_moving()
                with pytest.raises(DriveOffline):
                    await x.stop()  # refused at once: the drive is unreachable
                again = await start_server(servers, twin, port)
                await settle(m, "r")
                assert again.server.accepted == 1 and line.connected and x.error is None
                # it came back still moving, orphaned (mover got DriveOffline): stopped
                assert not twin.is_moving() and twin.position() < 3000
                await x.move_to(10.0)
                assert twin.position() == 1000
            await again.close()


async def test_leaving_the_machine_while_the_server_is_gone_does_not_hang() -> None:
    twin = SimEPR60(1)
    with anyio.fail_after(10):
        async with anyio.create_task_group() as servers:
            run = await start_server(servers, twin)
            async with open_machine(tcp_machine(HOST, tcp_port=run.server.port)) as m:
                x = m.axes["r"]
                await x.jog(20.0, watchdog=None)
                await run.close()
                async for _ in x.watch():
                    if x.state is AxisState.OFFLINE:
                        break
                assert isinstance(x.error, DriveOffline) and twin.is_moving()
            # The exit tried to stop the moving axis, failed (logged) and closed the line.
            assert not m.buses["eth"].is_open and not m.buses["eth"].line.connected



async def test_leaving_the_machine_right_after_a_network_blip_stops_the_drive() -> None:
    # Slow polls: the axis stays Offline for one moving-poll period (0.2 s) after the third
    # failed poll, though the server would answer again at once. We leave in that window.
    cfg = config(
        {"eth": {"kind": "tcp", "host": "sim://tcpdrop-exit", "timeout": 0.2, "retries": 0}},
        {"r": axis("eth", 1, "EPR60", speed=20.0,
                   poll={"moving": 0.2, "idle": 1.0, "offline_after": 3})},
    )
    with anyio.fail_after(10):
        async with open_machine(cfg) as m:
            srv, x, twin = m.wires["eth"], m.axes["r"], m.sim_drives["r"]
            assert isinstance(srv, SimTcpServer)
            async with anyio.create_task_group() as tg:
                tg.start_soon(when_moving, m, "r", lambda: srv.drop_next(3))
                with pytest.raises(DriveOffline):
                    await x.move_to(200.0)  # 10 s of travel
            assert x.state is AxisState.OFFLINE and twin.is_moving()
            served = srv.received
        # Leaving: the server was up all along and would have taken the stop.
        assert srv.received > served, "no stop was even attempted"
        assert not twin.is_moving()
