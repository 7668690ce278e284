"""USB-RS485 adapters: low-latency mode asked at open, the doctor's adapter report, and the
simulator's adapter model (latency timer, local echo) on ``sim://NAME?...`` lines.

Where no adapter exists here, the OS boundary is faked and nothing else: sysfs as a
directory tree, the TIOCGSERIAL/TIOCSSERIAL ioctls as a recording ``fcntl.ioctl``.
"""

from __future__ import annotations

import array
import os
import termios
import time
from pathlib import Path
from typing import Any

import pytest
import serial.serialposix

from drivebus import Bus, LineSettings, SerialLine
from drivebus.app.doctor import adapter_of, poll_efficiency
from drivebus.app.operations import check_config
from drivebus.config import parse_config
from drivebus.errors import ConfigError
from drivebus.motion import open_machine
from drivebus.sim import RegisterSlave, VirtualWire

ROOT = Path(__file__).resolve().parents[1]
SINGLE = ROOT / "configs" / "single.toml"
S = LineSettings.parse("115200 8N1")


async def test_a_pty_refuses_low_latency_and_the_line_goes_on() -> None:
    async with VirtualWire("adapter-pty") as wire:
        wire.attach(RegisterSlave(1, S, initial=[(0, 7)]))
        line = SerialLine(wire.slave_path, S)
        async with Bus(line, timeout=0.2) as bus:
            assert line.low_latency is False  # a pty has no serial_struct: silently refused
            assert await bus.slave(1).read_holding_registers(0, 1) == [7]


async def test_low_latency_is_asked_through_tiocsserial(monkeypatch: pytest.MonkeyPatch
                                                        ) -> None:
    """The ioctls a USB serial driver would get, recorded at the OS boundary."""
    calls: list[tuple[int, int]] = []
    real = serial.serialposix.fcntl.ioctl

    def ioctl(fd: int, request: int, arg: Any = 0, *rest: Any) -> Any:
        if request == termios.TIOCGSERIAL:
            assert isinstance(arg, array.array)
            calls.append((request, arg[4]))
            return 0  # flags 0, as a driver reports them
        if request == termios.TIOCSSERIAL:
            calls.append((request, arg[4]))
            return 0
        return real(fd, request, arg, *rest)

    monkeypatch.setattr(serial.serialposix.fcntl, "ioctl", ioctl)
    async with VirtualWire("adapter-ftdi") as wire:
        wire.attach(RegisterSlave(1, S, initial=[(0, 9)]))
        line = SerialLine(wire.slave_path, S)
        async with Bus(line, timeout=0.2) as bus:
            assert line.low_latency is True
            assert (termios.TIOCSSERIAL, 0x2000) in calls  # ASYNC_LOW_LATENCY set
            assert await bus.slave(1).read_holding_registers(0, 1) == [9]


def test_the_doctor_reports_the_adapter_and_what_the_line_reaches(tmp_path: Path) -> None:
    port = tmp_path / "dev" / "ttyUSB0"
    port.parent.mkdir()
    port.touch()
    sysfs = tmp_path / "sys"
    timer = sysfs / "bus" / "usb-serial" / "devices" / "ttyUSB0" / "latency_timer"
    timer.parent.mkdir(parents=True)
    timer.write_text("16\n")
    device = sysfs / "class" / "tty" / "ttyUSB0" / "device"
    device.mkdir(parents=True)
    (sysfs / "bus" / "usb-serial" / "drivers" / "ftdi_sio").mkdir(parents=True)
    os.symlink(sysfs / "bus" / "usb-serial" / "drivers" / "ftdi_sio", device / "driver")
    assert adapter_of(str(port), sysfs).driver == "ftdi_sio"
    cfg = tmp_path / "m.toml"
    cfg.write_text(SINGLE.read_text().replace('"sim://single"', f'"{port}"\nrs485 = true'))
    report = check_config(cfg, sysfs)
    (line,) = report.lines
    a = line.adapter
    assert a is not None and a["driver"] == "ftdi_sio" and a["latency_timer_ms"] == 16
    assert a["rs485_mode"] is True and a["local_echo"] is False
    assert a["efficiency_at_timer"] < 0.3 < a["efficiency_low_latency"] < a["efficiency_best"]
    wire, eff = poll_efficiency(S, 0.016)
    assert wire == pytest.approx(21 * 10 / 115200)
    assert round(eff, 3) == a["efficiency_at_timer"]


def _machine(port: str) -> Any:
    return parse_config({
        "lines": {"l": {"port": port, "settings": "115200 8N1", "timeout": 0.1}},
        "axes": {"x": {"line": "l", "address": 1, "drive": "CL86R", "pulses_per_rev": 1000,
                       "settings": "115200 8N1"}},
    })


async def _poll_rate(port: str, n: int = 20) -> float:
    async with open_machine(_machine(port)) as m:
        slave = m.axes["x"].profile.slave
        t = time.monotonic()
        for _ in range(n):
            await slave.read_holding_registers(0, 4)
        return n / (time.monotonic() - t)


async def test_a_simulated_16_ms_latency_timer_caps_the_line() -> None:
    slow = await _poll_rate("sim://adapter-slow?latency=16ms", n=20)
    # each reply waits for the timer's next tick: 20 polls one after the other span at
    # least 19 ticks, however fast the machine (an invariant, not a timing figure)
    assert slow <= 20 / (19 * 0.016)


async def test_simulated_local_echo_and_bad_adapter_options() -> None:
    cfg = parse_config({
        "lines": {"l": {"port": "sim://adapter-echo?echo=true", "settings": "115200 8N1",
                        "local_echo": True}},
        "axes": {"x": {"line": "l", "address": 1, "drive": "CL86R", "pulses_per_rev": 1000,
                       "settings": "115200 8N1"}},
    })
    async with open_machine(cfg) as m:
        assert m.wires["l"].echo is True
        assert await m.axes["x"].profile.slave.read_holding_registers(0, 1) == [862]
    with pytest.raises(ConfigError, match=r"latency=soon: a latency timer is 0\.\.1 s"):
        parse_config(_machine("sim://adapter-bad?latency=soon").model_dump())
    with pytest.raises(ConfigError, match=r"no option 'baud'"):
        parse_config(_machine("sim://adapter-bad?baud=9600").model_dump())


async def test_the_bench_shows_what_a_16_ms_timer_costs() -> None:
    from drivebus.bench import run_bench

    rows = await run_bench(quick=True, only={"adapter"})
    assert [r.case.split(", ")[1] for r in rows] == ["no timer", "1 ms timer", "16 ms timer"]
    slow = rows[2].figures
    # the slaves' own wire counts the replies: at most one per 16 ms tick
    assert isinstance(slow["transactions_per_s"], float)
    assert slow["transactions_per_s"] <= 1 / 0.016 * 1.02
