"""One master per line: another master's requests heard on a real line are reported as such
(``BusStats``, a warning, the line's status), apart from noise and from late replies; the
decision (``drivebus.line.foreign``) tested on its own, then on a line of ptys where a
pymodbus client is the other master and a pymodbus server the slave."""

from __future__ import annotations

import logging
import os
import random
import re
import subprocess
import sys
from typing import Any

import pytest

from drivebus import Bus, LineSettings, SerialLine, open_machine, runtime
from drivebus.app import line_snapshot
from drivebus.config import load_config
from drivebus.errors import LineClosed, ResponseTimeout
from drivebus.line.foreign import SCAN_LIMIT, describe_request, find_requests
from drivebus.line.receiver import BUFFER_LIMIT
from drivebus.line.rtu import frame
from drivebus.sim import Fault, RegisterSlave, VirtualWire, sim_bus
from drivebus.sim.machine import own_sim_lines
from drivebus.sim.serve import published
from peers import pty_line
from pymodbus_servers import PYMODBUS, server_data
from test_cli import DEMO, SINGLE, drivebus, sim_server, spawn
from waits import until, within

FAST = LineSettings.parse("115200 8N1")
READ = frame(5, bytes.fromhex("03 0000 0002"))  # another master reads slave 5
WRITE = frame(5, bytes.fromhex("06 0012 0001"))  # ... and writes its register 18


# -- the decision ---------------------------------------------------------------------------------


def test_requests_among_junk_are_found_and_described() -> None:
    junk = bytes((0xFF, 0x00, 0x55, 0x13))
    assert find_requests(junk + READ + junk + WRITE) == [READ, WRITE]
    assert describe_request(READ) == "read holding registers 0x0000 (2) from slave 5"
    assert describe_request(WRITE) == "write register 0x0012 = 0x0001 to slave 5"
    many = frame(7, bytes.fromhex("10 0046 0002 04 00c8 012c"))
    assert find_requests(many) == [many]
    assert describe_request(many) == "write registers 0x0046 (2) to slave 7"


def test_a_write_and_its_echo_count_once_and_replies_are_no_requests() -> None:
    # a slave's echo of another master's write is the same frame: one request
    assert find_requests(WRITE + WRITE) == [WRITE]
    # an FC03 reply parses as no request (its byte count is no register count)
    reply = frame(5, bytes.fromhex("03 04 0001 0002"))
    assert find_requests(READ + reply) == [READ]


def test_our_own_frames_and_late_replies_are_not_another_master() -> None:
    asked = [(5, 0x06), (5, 0x03)]
    # our echo (an adapter hearing itself), a late FC06 reply: both parse as requests
    # that we sent ourselves
    assert find_requests(WRITE, asked) == []
    # a late FC01 reply of 3 data bytes is also a plausible FC01 request: ours if we asked
    late = frame(2, bytes.fromhex("01 03 00 00 0a"))  # 17-24 coils: 0, 0, 0x0a
    assert find_requests(late) == [late]
    assert find_requests(late, [(2, 0x01)]) == []
    # a read of ours answers no write: another master's write to the same slave counts
    assert find_requests(WRITE, [(5, 0x03)]) == [WRITE]


def test_noise_is_not_another_master() -> None:
    """Random junk (64 KB of it, as much as a flooded line discards) holds no request:
    a request must have a plausible count and byte count as well as a good CRC."""
    rng = random.Random(33)
    junk = rng.randbytes(64 * 1024)
    chunks = [junk[i : i + SCAN_LIMIT] for i in range(0, len(junk), SCAN_LIMIT)]
    assert [f for c in chunks for f in find_requests(c)] == []
    # frames cut short or damaged are noise too
    assert find_requests(READ[:-1]) == []
    assert find_requests(READ[:-1] + bytes((READ[-1] ^ 1,))) == []


# -- on a line -------------------------------------------------------------------------------------


def _client_kwargs() -> dict[str, int]:
    return {"device_id": 1} if PYMODBUS >= (3, 10) else {"slave": 1}


async def _heard(bus: Bus, n: int, what: str) -> None:
    """Until ``n`` bytes nobody asked for wait in our port's receiver. A pty hands what
    the line's other ports sent to each port through the kernel's worker: on a busy
    machine our port may get the other master's frames after the other master got its
    reply (a real line carries them to every node at once), and a request of ours sent
    meanwhile would take the slave's late echo for its reply."""
    rx: Any = bus.line._rx  # type: ignore[attr-defined]  # (the rig's timing, not the API)
    await until(lambda: len(rx.buf) >= n, f"{what} in our port")


async def test_a_pymodbus_client_on_the_same_line_is_reported_as_another_master(
    caplog: pytest.LogCaptureFixture,
) -> None:
    from pymodbus.client import AsyncModbusSerialClient
    from pymodbus.server import ModbusSerialServer

    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    with within(30, "the two masters' transactions on the pty line"):
        async with pty_line(3) as (ours, theirs, slave_port):
            server = ModbusSerialServer(server_data({1: [11, 22, 33, 44]}), port=slave_port,
                                        baudrate=115200, parity="N", stopbits=1)
            await server.serve_forever(background=True)
            client = AsyncModbusSerialClient(theirs, baudrate=115200, timeout=2, retries=0)
            try:
                async with Bus(SerialLine(ours, FAST), timeout=0.5, retries=0) as bus:
                    h = bus.slave(1)
                    assert await h.read_holding_registers(0, 2) == [11, 22]
                    assert bus.stats.foreign_requests == 0  # our own traffic only
                    # the other master reads, then writes; we hear its frames on the line
                    assert await client.connect()
                    rr = await client.read_holding_registers(2, count=2, **_client_kwargs())
                    assert rr.registers == [33, 44]
                    await _heard(bus, 8 + 9, "the other master's read and its reply")
                    assert await h.read_holding_registers(0, 1) == [11]
                    assert bus.stats.foreign_requests == 1
                    assert bus.stats.foreign_last == \
                        "read holding registers 0x0002 (2) from slave 1"
                    wr = await client.write_register(3, 45, **_client_kwargs())
                    assert not wr.isError()
                    await _heard(bus, 8 + 8, "the other master's write and its echo")
                    assert await h.read_holding_registers(3, 1) == [45]
                    # the write and the slave's echo of it: one request
                    assert bus.stats.foreign_requests == 2
                    assert bus.stats.foreign_last == "write register 0x0003 = 0x002D to slave 1"
                    snap = line_snapshot("rs485", bus, "serial", ours).as_dict()
                    assert snap["foreign_requests"] == 2
                    assert snap["foreign_master"] == bus.stats.foreign_last
                    assert bus.stats.total().errors == 0  # heard, not mistaken for replies
            finally:
                client.close()
                await server.shutdown()
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING
              and "another master" in r.getMessage()]
    assert warned == [  # once, at once (then at most once a minute)
        f"{ours}: another master is on the line: it sent read holding registers 0x0002 (2) "
        f"from slave 1 (1 such requests heard so far); one master per line"]


async def test_noise_and_a_late_reply_on_a_line_are_not_another_master() -> None:
    slave = RegisterSlave(1, FAST)
    async with sim_bus([slave], FAST, timeout=0.05, retries=0) as (wire, bus):
        h = bus.slave(1)
        # a reply that comes after the timeout: an FC06 reply is the request's own frame
        slave.faults.inject(Fault.SLOW_REPLY, value=0.5)
        with pytest.raises(ResponseTimeout):
            await h.write_register(18, 7)
        with within(5, "the late reply on the wire"):
            await wire.wait_frames(2)
        assert await h.read_holding_registers(18, 1) == [7]
        assert bus.line.garbage_bytes == 8  # the late reply, discarded
        # a babbling device: noise, discarded before our next frame
        async with wire.babbling():
            await until(lambda: wire.noise_bytes > 2000, "2000 bytes of noise on the wire")
        assert await h.read_holding_registers(18, 1) == [7]
        assert bus.line.garbage_bytes > 2000 - BUFFER_LIMIT
        assert bus.stats.foreign_requests == 0


# -- on the simulator ------------------------------------------------------------------------


async def test_a_second_master_on_a_simulated_line_of_this_process_is_refused() -> None:
    async with VirtualWire("seat-private") as wire:
        wire.attach(RegisterSlave(1, FAST, initial=[(0, 862)]))
        async with Bus(SerialLine(wire.url, FAST)) as first:
            with pytest.raises(LineClosed) as refused:
                async with Bus(SerialLine(wire.url, FAST)):
                    pass
            assert re.search(rf"sim://seat-private already has a master: process "
                             rf"{os.getpid()} \(.*\), this one, has the simulated line open; "
                             rf"one master per line", str(refused.value)), refused.value
            assert await first.slave(1).read_holding_registers(0, 1) == [862]
        # the first master closed the line: the seat is free
        async with Bus(SerialLine(wire.url, FAST)) as second:
            assert await second.slave(1).read_holding_registers(0, 1) == [862]
    # a machine's simulated line has its master: the machine
    cfg = {"name": "seat", "lines": {"bus": {"port": "sim://seat-machine",
                                             "settings": "115200 8N1"}}, "axes": {}}
    async with open_machine(cfg):
        with pytest.raises(LineClosed, match=r"sim://seat-machine already has a master"):
            async with Bus(SerialLine("sim://seat-machine", FAST)):
                pass


def test_a_second_master_on_a_running_drivebus_sim_is_refused_naming_the_first() -> None:
    """Two processes on one ``sim://NAME`` of a ``drivebus sim``: the second is refused,
    naming the line and the process that has it; once the first is gone, it gets it."""
    first = ("import sys, anyio\n"
             "from drivebus import Bus, LineSettings, SerialLine\n"
             "async def main():\n"
             "    async with Bus(SerialLine('sim://single', LineSettings.parse('115200 8N1'))) "
             "as bus:\n"
             "        print(await bus.slave(1).read_holding_registers(0, 1), flush=True)\n"
             "        sys.stdin.readline()\n"
             "anyio.run(main)\n")
    with sim_server(SINGLE):
        holder = subprocess.Popen([sys.executable, "-c", first], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert holder.stdout is not None and holder.stdin is not None
            assert holder.stdout.readline().strip() == "[862]", holder.stderr
            r = drivebus("read", "sim://single", "1", "0", "-S", "115200 8N1")
            assert r.returncode != 0
            assert re.search(rf"sim://single already has a master: process {holder.pid} "
                             rf"\(.*python.*from drivebus import Bus.*\) has the simulated "
                             rf"line open; one master per line", r.stderr), r.stderr
            holder.stdin.close()
            assert holder.wait(30) == 0
        finally:
            if holder.poll() is None:
                holder.kill()
                holder.wait(10)
        r = drivebus("read", "sim://single", "1", "0", "-S", "115200 8N1")
        assert r.returncode == 0 and r.stdout.strip() == "[0]: 862", r.stderr


def test_a_master_that_took_no_seat_is_found_and_named() -> None:
    """A process with the pty open (mbpoll, a PLC) takes no seat: a drivebus master that
    comes second is refused naming it; one that came first hears of it from the sim once
    their frames collide."""
    raw = ("import os, sys, time\n"
           "fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)\n"
           "print('open', flush=True)\n"
           "request = bytes.fromhex(sys.argv[2])\n"
           "while not sys.stdin.closed:\n"
           "    if sys.argv[3] == 'talk':\n"
           "        os.write(fd, request)\n"
           "    time.sleep(0.005)\n")
    with sim_server(SINGLE) as (sim, ends):
        pty = ends["bus"]
        quiet = subprocess.Popen([sys.executable, "-c", raw, pty, "", "quiet"],
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        try:
            assert quiet.stdout is not None and quiet.stdout.readline() == "open\n"
            r = drivebus("read", "sim://single", "1", "0", "-S", "115200 8N1")
            assert r.returncode != 0
            assert f"sim://single already has a master: process {quiet.pid} (" in r.stderr, \
                r.stderr
        finally:
            quiet.kill()
            quiet.wait(10)
        # drivebus first (seated), then a raw master talking over it
        with spawn("monitor", SINGLE, "--interval", "0.02") as monitor:
            monitor.expect(r"x: CL86R")  # it polls: it has the line
            talk = subprocess.Popen([sys.executable, "-c", raw, pty,
                                     frame(1, bytes.fromhex("03 0000 0001")).hex(), "talk"],
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            try:
                assert talk.stdout is not None and talk.stdout.readline() == "open\n"
                m = sim.expect(r"warning: sim://single \(line bus\) has 2 masters: (.*) have "
                               r"it open and their frames collide; one master per line",
                               timeout=60)
                assert f"process {talk.pid} (" in m.group(1)
                assert f"process {monitor.popen.pid} (" in m.group(1)
            finally:
                talk.kill()
                talk.wait(10)


async def test_the_demo_machine_on_its_own_simulators_never_reaches_a_running_sim() -> None:
    """``drivebus demo`` runs configs/demo.toml on simulators named for its process
    (``own_sim_lines``): a drivebus sim serving sim://demo-rs485 for someone else (here a
    wire published under that name) is never reached."""
    cfg = load_config(DEMO)
    own = own_sim_lines(cfg)
    assert own.lines["rs485"].port == f"sim://demo-rs485-{os.getpid()}"
    assert own.lines["eth"].host == f"sim://demo-eth-{os.getpid()}"
    assert own.axes == cfg.axes and own.name == cfg.name
    with_options = cfg.model_copy(update={"lines": {"rs485": cfg.lines["rs485"].model_copy(
        update={"port": "sim://demo-rs485?latency=16ms"})}})
    assert own_sim_lines(with_options).lines["rs485"].port == \
        f"sim://demo-rs485-{os.getpid()}?latency=16ms"
    async with VirtualWire("someone-elses-demo-rs485") as served:
        with runtime.publish("sim", {"demo-rs485": [served.slave_path]}):
            assert published("demo-rs485") is not None  # a plain open would go there
            async with open_machine(own) as m:
                await m.axes["x"].move_by(1.0)
                assert set(m.sim_drives) == set(cfg.axes)
        assert served.request_count == 0
