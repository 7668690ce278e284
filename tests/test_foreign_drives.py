"""Drives drivebus has never seen, described from their public manuals in the description
format only, and driven through the public API against an INDEPENDENT emulator.

The Leadshine PR-mode stepper (configs/drives/leadshine_pr.toml) is written from the
manual's parameter list, as an outside user writes it. Its emulator below is a pymodbus
RTU server whose register behaviour is written from the same manual's words (the trigger
register, the PR path 0 block, the motion status bits, homing, alarm reset) with a simple
kinematic of its own — nothing of ``drivebus.sim`` is used. The machine file names the
description by path, as a user's does, and talks to the emulator over a pty null-modem
(the real serial stack). The same description also passes ``drivebus drive try`` against
the generic twin drivebus builds from it. The ZLTECH ZLAC8015D (left channel), whose
register list reports neither an enable state nor running, runs beside them and a seed
drive in one machine.
"""

from __future__ import annotations

import itertools
import logging
import math
import re
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Collection
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import anyio
import anyio.to_thread
import pytest
from pymodbus.server import ModbusSerialServer, ModbusTcpServer

from drivebus import AxisState, LineSettings, open_machine
from drivebus.drives.base import MoveParams
from drivebus.drives.description import Description, load_description
from drivebus.drives.engine import profile_class
from drivebus.errors import (
    ConfigError,
    LimitViolation,
    ModbusException,
    MotionAborted,
    StateError,
)
from drivebus.sim import sim_bus
from drivebus.sim.described import described_twin
from pymodbus_servers import PYMODBUS
from test_pymodbus_peer import null_modem

ROOT = Path(__file__).resolve().parents[1]
LEADSHINE = ROOT / "configs" / "drives" / "leadshine_pr.toml"
FAST = LineSettings.parse("115200 8N1")
HOST = "127.0.0.1"

pytestmark = pytest.mark.skipif(PYMODBUS < (3, 13), reason="SimDevice actions: pymodbus 3.13+")


# == an independent Leadshine PR-mode emulator (from the manual, not from drivebus.sim) ========

# The manual's addresses (hex, as on the wire) and factory values.
PPR, ENABLE, STATUS, CONTROL, ALARM = 0x0001, 0x000F, 0x1003, 0x1801, 0x2203
TRIGGER, HOME_MODE, HOME_FAST, HOME_SLOW, HOME_ACC, HOME_DEC = (
    0x6002, 0x600A, 0x600F, 0x6010, 0x6011, 0x6012)
POS_HI, POS_LO, SPEED_NOW = 0x602A, 0x602B, 0x6030
PR_MODE, PR_POS_HI, PR_POS_LO, PR_SPEED, PR_ACC, PR_DEC = (
    0x6200, 0x6201, 0x6202, 0x6203, 0x6204, 0x6205)
FACTORY = {
    PPR: 10000, ENABLE: 0, STATUS: 0, CONTROL: 0, ALARM: 0, TRIGGER: 0, HOME_MODE: 0,
    HOME_FAST: 200, HOME_SLOW: 50, HOME_ACC: 100, HOME_DEC: 100, POS_HI: 0, POS_LO: 0,
    SPEED_NOW: 0, PR_MODE: 1, PR_POS_HI: 0, PR_POS_LO: 0, PR_SPEED: 60, PR_ACC: 100,
    PR_DEC: 100,
}
READ_ONLY = {STATUS, ALARM, POS_HI, POS_LO, SPEED_NOW}
# Motion status 0x1003: bit 0 fault, 1 enabled, 2 running, 4 command completed,
# 5 path completed, 6 homing completed.
FAULT, ENABLED, RUNNING, CMD_DONE, PATH_DONE, HOMED = 1, 2, 4, 16, 32, 64
DT = 0.0005  # the emulator's integration step, s


def _signed16(w: int) -> int:
    return w - 0x10000 if w & 0x8000 else w


@dataclass
class Kinematic:
    """A motor on a trapezoidal profile (pulses, pulses/s, pulses/s²), advanced in fixed
    steps up to each access; ``edge`` ends a search motion at a switch."""

    limit_negative: float = -30000.0
    """Where the negative limit switch sits (pulses)."""
    home_switch: float = -12000.0
    """Where the home switch's edge sits (pulses)."""
    pos: float = 0.0
    vel: float = 0.0
    """pulses/s, signed."""
    motion: str | None = None
    """None (at rest), "position", "speed", "stopping" or "homing"."""
    target: float = 0.0
    """The position to reach, or the signed speed to run at."""
    vmax: float = 0.0
    acc: float = 1.0
    dec: float = 1.0
    edge: float = 0.0
    """The switch position a homing search ends at."""
    t: float = field(default_factory=time.monotonic)

    @property
    def position(self) -> int:
        return round(self.pos)

    def advance(self, now: float) -> None:
        while self.t + DT <= now:
            self.t += DT
            self._step()

    def _step(self) -> None:
        m = self.motion
        if m is None:
            return
        if m == "position":
            dist = self.target - self.pos
            if abs(dist) < 0.5:
                self.rest(self.target)
                return
            d = math.copysign(1.0, dist)
            allowed = math.sqrt(2.0 * self.dec * abs(dist))
            v = min(abs(self.vel) + self.acc * DT, self.vmax, allowed) if self.vel * d >= 0 \
                else 0.0
            self.vel = d * v
            nxt = self.pos + self.vel * DT
            if (self.target - nxt) * d <= 0:
                self.rest(self.target)
                return
            self.pos = nxt
        elif m in ("speed", "homing"):
            want = self.target  # the signed speed
            rate = self.acc if abs(want) >= abs(self.vel) and want * self.vel >= 0 else self.dec
            step = rate * DT
            self.vel = want if abs(want - self.vel) <= step else \
                self.vel + math.copysign(step, want - self.vel)
            self.pos += self.vel * DT
            if m == "homing" and (self.pos - self.edge) * math.copysign(1.0, self.vel) >= 0:
                self.homed_at_edge()
                return
        elif m == "stopping":
            step = self.dec * DT
            if abs(self.vel) <= step:
                self.rest(self.pos)
                self.stopped()
                return
            self.vel -= math.copysign(step, self.vel)
            self.pos += self.vel * DT
        if self.pos <= self.limit_negative and self.vel < 0 and m != "homing":
            self.rest(self.limit_negative)  # its limit input stops the motor at once

    def rest(self, pos: float) -> None:
        self.pos, self.vel, self.motion = pos, 0.0, None

    def stop_with(self, dec: float) -> None:
        """Decelerate to rest at ``dec``."""
        if self.motion is not None:
            self.dec, self.motion = dec, "stopping"

    def homed_at_edge(self) -> None:
        """A homing search reached its switch: the drive's own reaction."""
        self.rest(0.0)

    def stopped(self) -> None:
        """A decelerating stop came to rest."""


@dataclass
class Leadshine(Kinematic):
    """One drive: its registers, advanced at each access."""

    regs: dict[int, int] = field(default_factory=lambda: dict(FACTORY))
    homed: bool = False
    alarm: int = 0
    writes: list[tuple[int, list[int]]] = field(default_factory=list)
    """Every write received: (address, values)."""

    # -- units as the manual gives them -----------------------------------------------------

    def pps(self, rpm: float) -> float:
        return rpm / 60.0 * self.regs[PPR]

    def rate(self, ms_per_1000rpm: int) -> float:
        """pulses/s² of a ramp time in ms per 1000 rpm."""
        return self.pps(1000.0) / (max(ms_per_1000rpm, 1) / 1000.0)

    @property
    def enabled(self) -> bool:
        return self.regs[ENABLE] == 1

    def homed_at_edge(self) -> None:
        self.homed = True
        self.rest(0.0)  # the found origin becomes position 0 (Pr8.11/12 = 0)

    # -- what the registers do (the manual's words) ----------------------------------------

    def on_write(self, address: int, values: list[int]) -> None:
        self.writes.append((address, list(values)))
        for i, v in enumerate(values):
            self.regs[address + i] = v
        written = range(address, address + len(values))
        if ENABLE in written and not self.enabled:
            self.rest(self.pos)  # disabled: the motor is released at once
        if CONTROL in written and self.regs[CONTROL] == 0x1111:
            self.alarm = 0
        if TRIGGER in written:
            self.trigger(self.regs[TRIGGER])

    def trigger(self, value: int) -> None:
        if value == 0x0040:  # stop the path with its deceleration
            self.stop_with(self.rate(self.regs[PR_DEC]))
            return
        if value == 0x0021:
            self.pos = 0.0
            return
        if not self.enabled or self.alarm:
            return  # "the drive must be enabled and free of alarms to run a path"
        if value == 0x0010 and self.motion is None:
            mode = self.regs[PR_MODE]
            speed = _signed16(self.regs[PR_SPEED])
            self.acc, self.dec = self.rate(self.regs[PR_ACC]), self.rate(self.regs[PR_DEC])
            if mode & 0x0F == 2:
                self.motion, self.target = "speed", self.pps(speed)
                return
            p = (self.regs[PR_POS_HI] << 16) | self.regs[PR_POS_LO]
            p = p - (1 << 32) if p & 0x80000000 else p
            self.target = self.pos + p if mode & 0x40 else float(p)
            self.vmax = abs(self.pps(speed))
            self.motion = "position"
        elif value == 0x0020 and self.motion is None:
            mode = self.regs[HOME_MODE]
            d = 1.0 if mode & 1 else -1.0
            self.homed = False
            self.acc = self.dec = self.rate(self.regs[HOME_ACC])
            self.edge = self.home_switch if mode & 4 else self.limit_negative
            self.motion, self.target = "homing", d * self.pps(self.regs[HOME_FAST])

    def raise_alarm(self, code: int) -> None:
        self.alarm = code
        self.rest(self.pos)  # a fault stops the motor at once

    def status_word(self) -> int:
        w = (FAULT if self.alarm else 0) | (ENABLED if self.enabled else 0)
        if self.motion is not None:
            w |= RUNNING
        else:
            w |= CMD_DONE | PATH_DONE
        return w | (HOMED if self.homed else 0)

    def refresh(self, now: float) -> None:
        self.advance(now)
        p = self.position & 0xFFFFFFFF
        rpm = round(self.vel / self.regs[PPR] * 60.0)
        self.regs.update({STATUS: self.status_word(), ALARM: self.alarm, POS_HI: p >> 16,
                          POS_LO: p & 0xFFFF, SPEED_NOW: rpm & 0xFFFF})

    async def action(self, function: int, start: int, address: int, count: int,
                     registers: list[int], values: Any) -> Any:
        """pymodbus's hook on every access: bring the registers up to date, act on writes."""
        from pymodbus.constants import ExcCodes

        self.refresh(time.monotonic())
        if values is not None:
            if PR_SPEED in range(address, address + count) and \
                    abs(_signed16(values[PR_SPEED - address])) > 3000:
                return ExcCodes.ILLEGAL_VALUE  # "out of range: exception 03"
            self.on_write(address, list(values))
            self.refresh(time.monotonic())
        for a, v in self.regs.items():
            registers[a - start] = v
        return None


@asynccontextmanager
async def serving(device: list[Any], transport: str = "rtu",
                  settings: tuple[int, str, int] = (115200, "N", 1)
                  ) -> AsyncIterator[dict[str, Any]]:
    """pymodbus serving ``device`` (its ``SimDevice`` list): RTU on one end of a null modem
    at ``settings`` (baud, parity, stop bits), or Modbus TCP on loopback; yields the
    machine file's line for it."""
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    line = {"timeout": 0.3, "retries": 1}
    if transport == "tcp":
        server: Any = ModbusTcpServer(device, address=(HOST, 0))
        await server.serve_forever(background=True)
        try:
            yield {"kind": "tcp", "host": HOST,
                   "tcp_port": server.transport.sockets[0].getsockname()[1], **line}
        finally:
            await server.shutdown()
        return
    baud, parity, stop = settings
    async with null_modem() as (ours, theirs):
        server = ModbusSerialServer(device, port=theirs, baudrate=baud, parity=parity,
                                    stopbits=stop)
        await server.serve_forever(background=True)
        try:
            yield {"port": ours, "settings": f"{baud} 8{parity}{stop}", **line}
        finally:
            await server.shutdown()


def register_device(regs: dict[int, int], action: Any, read_only: Collection[int],
                    unit: int = 1) -> list[Any]:
    """A pymodbus device of holding registers ``regs`` with the hook ``action``; addresses
    it does not have answer exception 02."""
    from pymodbus.simulator import DataType, SimData, SimDevice

    data = [SimData(a, values=[v], datatype=DataType.REGISTERS, readonly=a in read_only)
            for a, v in sorted(regs.items())]
    return [SimDevice(unit, simdata=data, action=action)]


@asynccontextmanager
async def served(drive: Any, read_only: Collection[int], transport: str = "rtu",
                 unit: int = 1) -> AsyncIterator[dict[str, Any]]:
    """An emulated drive (its ``regs`` and ``action``) served by pymodbus at 115200 8N1 or
    over TCP; yields the machine file's line for it."""
    async with serving(register_device(drive.regs, drive.action, read_only, unit),
                       transport) as line:
        yield line


def machine(line: dict[str, Any], drive: Path = LEADSHINE) -> dict[str, Any]:
    """A machine file with one axis on the emulated drive, its description by path."""
    return {
        "name": "foreign",
        "lines": {"bus": line},
        "axes": {"a": {
            "line": "bus", "address": 1, "drive": str(drive), "pulses_per_rev": 10000,
            "units_per_rev": 10.0, "unit": "mm", "speed": 60.0, "accel": 600.0,
            "decel": 600.0, "limits": [-20.0, 200.0], "poll": {"moving": 0.01, "idle": 0.05},
            "homing": {"method": "negative_limit", "speed": 60.0, "creep": 10.0,
                       "accel": 600.0},
        }},
    }


async def until_at(twin: Any, position: int) -> bool:
    """Wait (bounded) for a twin to come to rest; whether it is at ``position``."""
    with anyio.fail_after(5):
        while twin.is_moving():  # noqa: ASYNC110 - the twin is the judge
            await anyio.sleep(0.005)
    return bool(twin.position() == position)


async def until(cond: Any, timeout: float = 5.0) -> None:
    """Wait (bounded) for a condition on the emulator's state."""
    with anyio.fail_after(timeout):
        while not cond():  # noqa: ASYNC110 - the emulator has no event to wait on
            await anyio.sleep(0.005)


@pytest.mark.parametrize("transport", ["rtu", "tcp"])
async def test_the_leadshine_description_drives_an_independent_emulator(transport: str) -> None:
    drive = Leadshine()
    with anyio.fail_after(60):
        async with served(drive, READ_ONLY, transport) as line, \
                open_machine(machine(line)) as m:
            a = m.axes["a"]
            await a.enable()
            assert drive.enabled and drive.writes[0] == (PPR, [10000])  # setup: Pr0.00 first
            await a.move_to(20.0)
            assert drive.position == 20000 and a.position == 20.0
            assert a.state is AxisState.STANDSTILL
            # One FC16 for the path block, then the trigger: mode, position (high word
            # first), speed 360 rpm, ramps of 60 rev/s² in ms per 1000 rpm = 278.
            block, trig = drive.writes[-2:]
            assert block == (PR_MODE, [0x0001, 0, 20000, 360, 278, 278])
            assert trig == (TRIGGER, [0x0010])
            await a.move_by(-25.0)
            assert drive.position == -5000 and drive.writes[-2][1][0] == 0x0041
            # A jog (within soft limits: a path to the limit at the jog speed), then a stop
            # that decelerates with the path's deceleration.
            await a.jog(-5.0, watchdog=None)
            await until(lambda: drive.vel < 0)
            assert drive.regs[PR_SPEED] == 30 and drive.target == -20000
            await a.stop()
            assert drive.motion is None and drive.vel == 0.0
            assert drive.writes[-1] == (TRIGGER, [0x0040])
            # Homing on the negative limit switch: Pr8.10 = 0, trigger 0x20; position 0.
            await a.home()
            assert drive.homed and drive.position == 0 and a.homed
            assert (HOME_MODE, [0]) in drive.writes and (TRIGGER, [0x0020]) in drive.writes
            # Soft limits: nothing is written for a move beyond them.
            sent = len(drive.writes)
            with pytest.raises(LimitViolation):
                await a.move_to(500.0)
            assert len(drive.writes) == sent
            # An alarm of the drive reaches the axis with the manual's text; reset clears.
            await a.jog(5.0, watchdog=None)
            await until(lambda: drive.vel > 0)
            drive.raise_alarm(0x80)
            with anyio.fail_after(5):
                async for st in a.watch():
                    if st.alarm:
                        break
            assert st.alarm_text == "lock shaft fault (stall)"
            with pytest.raises(StateError, match=r"drive alarm 128: lock shaft fault"):
                await a.move_to(10.0)
            await a.reset()
            assert drive.alarm == 0 and (CONTROL, [0x1111]) in drive.writes
            # The emergency stop: halt_now stops the running path.
            await a.enable()
            await a.jog(5.0, watchdog=None)
            await until(lambda: drive.vel > 0)
            await a.halt_now()
            await until(lambda: drive.motion is None, timeout=2.0)
            # its shortest ramp as the raw value 1 (`raw = true`), then the stop trigger
            assert drive.writes[-2:] == [(PR_DEC, [1]), (TRIGGER, [0x0040])]
            await a.disable()
            assert not drive.enabled


def drive(command: str, path: Path) -> str:
    """``drivebus drive COMMAND PATH`` as a user runs it: its output, after a zero exit."""
    done = subprocess.run([sys.executable, "-m", "drivebus.cli", "drive", command, str(path)],
                          capture_output=True, text=True, timeout=120, check=False, cwd=ROOT)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def drive_try(path: Path) -> str:
    """``drivebus drive try PATH``: its table of steps."""
    return drive("try", path)


def test_the_leadshine_description_passes_its_trial() -> None:
    assert "12 passed, 0 failed, 0 skipped" in drive_try(LEADSHINE)


# == an independent CiA 402 emulator of the Kinco FD (from CiA 402 and the Kinco manual) ======

KINCO = ROOT / "configs" / "drives" / "kinco_fd.toml"
# The Kinco FD's Modbus addresses of the CiA 402 objects; 32-bit objects LOW word first.
K_CW, K_SW, K_QS_DEC, K_MODE, K_POS, K_VEL = 0x3100, 0x3200, 0x3300, 0x3500, 0x3700, 0x3B00
K_TARGET, K_OFFSET, K_SPEED, K_ACC, K_DEC, K_METHOD = 0x4000, 0x4100, 0x4A00, 0x4B00, 0x4C00, \
    0x4D00
K_HM_FAST, K_HM_SLOW, K_HM_ACC, K_DIN, K_TARGET_VEL = 0x5010, 0x5020, 0x5200, 0x6D00, 0x6F00
K_MODE_SHOWN = 0x3600  # modes of operation display (6061)
K_ERROR = 0x1F00  # Error_State (2601.00), one bit per error: the manual's alarm code
K_WIDE = {K_QS_DEC, K_POS, K_VEL, K_TARGET, K_OFFSET, K_SPEED, K_ACC, K_DEC, K_HM_FAST,
          K_HM_SLOW, K_HM_ACC, K_DIN, K_TARGET_VEL}
K_ONE = {K_CW, K_SW, K_MODE, K_MODE_SHOWN, K_METHOD, K_ERROR}
K_READ_ONLY = {K_SW, K_ERROR, K_MODE_SHOWN, K_POS, K_POS + 1, K_VEL, K_VEL + 1, K_DIN, K_DIN + 1}
SPEED_DEC = 2048 / 125  # DEC per pulse/s
ACC_DEC = 256 / 15625  # DEC per pulse/s²
# CiA 402 statusword: the state bits, remote (9), voltage enabled (4) and the mode bits.
SW_STATE = {"switch_on_disabled": 0x0250, "ready": 0x0231, "switched_on": 0x0233,
            "enabled": 0x0237, "quick_stop": 0x0217, "fault": 0x0218}


@dataclass
class Kinco(Kinematic):
    """The drive's side of CiA 402 as the standard says it: the device control state
    machine on the controlword, profile position with the set-point handshake (bit 4
    edge, acknowledge bit 12, change set immediately bit 5, relative bit 6), halt (bit 8),
    quick stop (option code 2: ramp down, then Switch on disabled), profile velocity and
    homing methods 17, 18 and 35."""

    regs: dict[int, int] = field(default_factory=dict)
    mode_lag: float = 0.0
    """How long the drive takes to change modes (s): until then it works in the old mode
    and its display (6061) shows that one."""
    mode_set: tuple[float, int, int] = (0.0, 0, 0)
    """(when, the mode before, the mode written) of the last mode written."""
    state: str = "switch_on_disabled"
    cw: int = 0
    ack: bool = False
    halted: bool = False
    homing_done: bool = False
    homing_error: bool = False
    home_found: bool = False
    """Statusword bit 15: "bit15=1 indicates home is found" (FD5P manual ch. 10, table
    10-1); set by a completed homing, kept until the next one starts."""
    set_points: list[tuple[int, int]] = field(default_factory=list)
    """(controlword, target) of every set-point the drive took."""
    states: list[str] = field(default_factory=list)
    """Every state the drive entered, in order."""

    def __post_init__(self) -> None:
        for a in K_ONE:
            self.regs[a] = 0
        for a in K_WIDE:
            self.regs[a] = self.regs[a + 1] = 0
        self.put32(K_QS_DEC, 6100)  # its factory quick stop deceleration (DEC)

    def u32(self, a: int) -> int:
        return self.regs[a] | self.regs[a + 1] << 16

    def s32(self, a: int) -> int:
        v = self.u32(a)
        return v - (1 << 32) if v & 0x80000000 else v

    def put32(self, a: int, v: int) -> None:
        v &= 0xFFFFFFFF
        self.regs[a], self.regs[a + 1] = v & 0xFFFF, v >> 16

    @property
    def mode(self) -> int:
        """The mode the drive works in (the one written, once it has changed to it)."""
        when, before, written = self.mode_set
        return written if self.t - when >= self.mode_lag else before

    def enter(self, state: str) -> None:
        if state != self.state:
            self.state = state
            self.states.append(state)
        if state != "enabled" and state != "quick_stop":
            self.rest(self.pos)  # no torque: the motor stands (a brake holds it)

    # -- the controlword --------------------------------------------------------------------

    def controlword(self, cw: int) -> None:
        prev, self.cw = self.cw, cw
        st = self.state
        if st == "fault":
            if cw & 0x80 and not prev & 0x80:
                self.regs[K_ERROR] = 0
                self.enter("switch_on_disabled")
            return
        low = cw & 0x8F
        if not cw & 0x02:
            self.enter("switch_on_disabled")  # disable voltage
        elif not cw & 0x04:  # quick stop
            if st == "enabled":
                self.state = "quick_stop"
                self.states.append("quick_stop")
                self.stop_with(self.u32(K_QS_DEC) / ACC_DEC)
                if self.motion is None:
                    self.enter("switch_on_disabled")
            elif st != "quick_stop":
                self.enter("switch_on_disabled")
        elif low & 0x07 == 0x06:  # shutdown
            if st in ("switch_on_disabled", "switched_on", "enabled"):
                self.enter("ready")
        elif low & 0x0F == 0x07:  # switch on / disable operation
            if st in ("ready", "enabled"):
                self.enter("switched_on")
        elif low & 0x0F == 0x0F and st in ("ready", "switched_on", "quick_stop"):
            self.enter("enabled")  # switch on + enable operation / enable operation
        if self.state == "enabled":
            self.operate(prev, cw)

    def operate(self, prev: int, cw: int) -> None:
        rising = cw & 0x10 and not prev & 0x10
        if not cw & 0x10:
            self.ack = False
        halt = bool(cw & 0x100)
        if halt and not self.halted:
            self.halted = True
            self.stop_with(self.u32(K_DEC) / ACC_DEC)
        elif not halt and self.halted:
            self.halted = False
            if self.mode == 1 and self.motion is None and self.position != round(self.target):
                self.go_to(self.target)  # the interrupted positioning goes on
        if self.mode == 1 and rising and not halt:
            busy = self.motion == "position"
            if busy and not cw & 0x20:
                return  # no buffer here: refused until the running one ends
            base = self.target if busy else self.pos
            p = self.s32(K_TARGET)
            self.set_points.append((cw, p))
            self.go_to(base + p if cw & 0x40 else float(p))
            self.ack = True
        elif self.mode == 3 and not halt:
            self.run_velocity()
        elif self.mode == 6 and rising and not halt:
            self.start_homing()

    def go_to(self, target: float) -> None:
        self.target, self.motion = target, "position"
        self.vmax = self.u32(K_SPEED) / SPEED_DEC
        self.acc, self.dec = self.u32(K_ACC) / ACC_DEC, self.u32(K_DEC) / ACC_DEC

    def run_velocity(self) -> None:
        self.acc, self.dec = self.u32(K_ACC) / ACC_DEC, self.u32(K_DEC) / ACC_DEC
        self.motion, self.target = "speed", self.s32(K_TARGET_VEL) / SPEED_DEC

    def start_homing(self) -> None:
        method = _signed16(self.regs[K_METHOD])
        self.homing_done = self.homing_error = self.home_found = False
        if method in (35, 37):
            self.rest(float(self.s32(K_OFFSET)))
            self.homing_done = self.home_found = True
            return
        if method not in (17, 18):
            self.homing_error = True
            return
        self.edge = self.limit_negative if method == 17 else -self.limit_negative
        fast = self.u32(K_HM_FAST) / SPEED_DEC
        self.acc = self.dec = self.u32(K_HM_ACC) / ACC_DEC
        self.motion, self.target = "homing", -fast if method == 17 else fast

    def homed_at_edge(self) -> None:
        self.rest(float(self.s32(K_OFFSET)))
        self.homing_done = self.home_found = True

    def stopped(self) -> None:
        if self.state == "quick_stop":
            self.enter("switch_on_disabled")

    def raise_fault(self, error_state: int = 0x0004) -> None:
        self.rest(self.pos)
        self.regs[K_ERROR] = error_state
        self.enter("fault")

    # -- the statusword and the other read-only objects --------------------------------------

    def statusword(self) -> int:
        sw = SW_STATE[self.state] | (0x8000 if self.home_found else 0)
        if self.state != "enabled":
            return sw
        m = self.mode
        if m == 1:
            reached = self.motion is None and (self.halted or self.position == round(self.target))
            sw |= (0x400 if reached else 0) | (0x1000 if self.ack else 0)
        elif m == 3:
            sw |= 0x400 if self.vel == self.target or (self.halted and self.vel == 0) else 0
            sw |= 0x1000 if self.vel == 0 else 0
        elif m == 6:
            sw |= (0x1400 if self.homing_done else 0) | (0x2000 if self.homing_error else 0)
            if self.halted and self.motion is None:
                sw |= 0x400
        return sw

    def refresh(self, now: float) -> None:
        self.advance(now)
        self.regs[K_SW] = self.statusword()
        self.regs[K_MODE_SHOWN] = self.mode & 0xFFFF
        self.put32(K_POS, self.position)
        self.put32(K_VEL, round(self.vel * SPEED_DEC))
        din = (1 if self.pos <= self.limit_negative else 0) | \
            (2 if self.pos >= -self.limit_negative else 0)
        self.put32(K_DIN, din)

    async def action(self, function: int, start: int, address: int, count: int,
                     registers: list[int], values: Any) -> Any:
        """pymodbus's hook: objects up to date on every access; writes act."""
        self.refresh(time.monotonic())
        if values is not None:
            for i, v in enumerate(values):
                self.regs[address + i] = v
            span = range(address, address + len(values))
            if K_MODE in span:
                self.mode_set = (self.t, self.mode, _signed16(self.regs[K_MODE]))
            if K_CW in span:
                self.controlword(self.regs[K_CW])
            elif (K_TARGET_VEL in span and self.state == "enabled" and self.mode == 3
                  and not self.halted):
                self.run_velocity()
            self.refresh(time.monotonic())
        for a, v in self.regs.items():
            registers[a - start] = v
        return None


async def test_the_kinco_description_drives_an_independent_cia402_emulator() -> None:
    drive = Kinco()
    with anyio.fail_after(60):
        async with served(drive, K_READ_ONLY) as line, \
                open_machine(machine(line, KINCO)) as m:
            a = m.axes["a"]
            await a.enable()
            assert drive.state == "enabled"
            assert drive.states == ["ready", "switched_on", "enabled"] or \
                drive.states == ["ready", "enabled"]
            await a.move_to(20.0)
            assert drive.position == 20000 and a.state is AxisState.STANDSTILL
            assert drive.set_points[-1][1] == 20000 and not drive.ack
            await a.move_by(-5.0)
            assert drive.position == 15000
            # A stop mid-move, then a move elsewhere: the new set-point, not the old.
            move = anyio.Event()

            async def far() -> None:
                with pytest.raises(MotionAborted):
                    await a.move_to(150.0)
                move.set()

            async with anyio.create_task_group() as tg:
                tg.start_soon(far)
                await until(lambda: drive.vel > 0)
                await a.stop()
                await move.wait()
            stopped_at = drive.position
            assert 15000 < stopped_at < 150000 and drive.motion is None
            await a.move_to(10.0)
            assert drive.position == 10000 and drive.set_points[-1] == (0x3F, 10000)
            # Homing on the negative limit switch (method 17): position = offset 0.
            await a.home()
            assert drive.homing_done and drive.position == 0 and a.homed
            # A jog and an emergency stop (quick stop): the drive ramps down.
            await a.jog(5.0, watchdog=None)
            await until(lambda: drive.vel > 0)
            await a.halt_now()
            await until(lambda: drive.motion is None, timeout=2.0)
            assert drive.states[-2:] == ["quick_stop", "switch_on_disabled"]  # option code 2
            # A fault, then the reset: fault reset is bit 7's rising edge.
            await a.enable()
            drive.raise_fault(0x0004)
            with anyio.fail_after(5):
                async for st in a.watch():
                    if st.alarm:
                        break
            assert st.alarm_code == 0x0004  # Error_State (0x1F00), not the statusword
            await a.reset()
            assert drive.state != "fault"
            await a.enable()
            await a.move_to(5.0)
            assert drive.position == 5000


# == what the format gained from these drives =================================================


def variant(tmp_path: Path, old: str, new: str, name: str = "variant.toml") -> Path:
    """The Leadshine description with ``old`` replaced by ``new``, as a file."""
    text = LEADSHINE.read_text(encoding="utf-8")
    assert old in text, old
    path = tmp_path / name
    path.write_text(text.replace(old, new), encoding="utf-8")
    return path


async def test_a_raw_write_is_range_checked_before_any_frame(tmp_path: Path) -> None:
    desc = load_description(variant(tmp_path, "{ value = 1, raw = true }",
                                    "{ value = 0, raw = true }"))
    twin = described_twin(desc)(1, FAST)
    async with sim_bus([twin], FAST) as (wire, bus):
        profile = profile_class(desc)(bus.slave(1))
        with pytest.raises(LimitViolation, match=r"PR0 deceleration time .* outside its "
                                                  r"range 1\.\.32767"):
            await profile.emergency_stop()
        assert wire.requests() == []
    with pytest.raises(ConfigError, match=r"variant\.toml: procedures\.emergency_stop\."
                                          r"steps\[0\]\.write\.pr_decel\.raw: "):
        load_description(variant(tmp_path, "raw = true", 'raw = "maybe"'))


async def test_the_bus_keeps_a_drives_guard_interval_and_frame_timeout(tmp_path: Path) -> None:
    """``[link.timing]``: the line stays quiet ``guard`` longer before each frame to the
    guarded drive, and ``frame_timeout`` longer after each reply of the drive that trails
    bytes; the wire log's silences show it (lower bounds only: load only lengthens them)."""
    def descriptions() -> tuple[Description, Description, Description]:
        return (load_description(variant(tmp_path, "max_read = 32\n",
                                          "max_read = 32\ntiming = { guard = 0.02 }\n",
                                          "g.toml")),
                load_description(variant(tmp_path, "max_read = 32\n",
                                         "max_read = 32\ntiming = { frame_timeout = 0.03 }\n",
                                         "t.toml")),
                load_description(LEADSHINE))

    # (three descriptions parsed: the test's own setup, off the loop the bus shares)
    guarded, trailing, plain = await anyio.to_thread.run_sync(descriptions)
    twins = [described_twin(d)(a, FAST) for a, d in ((1, guarded), (2, trailing), (3, plain))]
    async with sim_bus(twins, FAST) as (wire, bus):
        profiles = [profile_class(d)(bus.slave(a))
                    for a, d in ((1, guarded), (2, trailing), (3, plain))]
        assert (profiles[0].slave.guard, profiles[1].slave.frame_timeout) == (0.02, 0.03)
        wire.clear_log()
        for _ in range(3):
            for p in profiles:
                await p.read_status()
        frames = [f for f in wire.log if f.note == ""]
    to_guarded = [f for f in frames if f.direction == "request" and f.address == 1]
    after_trailing = [b for a, b in itertools.pairwise(frames)
                      if a.direction == "reply" and a.address == 2]
    assert len(to_guarded) >= 3 and len(after_trailing) >= 2
    assert min(f.gap for f in to_guarded) >= 0.02
    assert min(f.gap for f in after_trailing) >= 0.03
    with pytest.raises(ConfigError, match=r"link\.timing\.guard: "):
        load_description(variant(tmp_path, "max_read = 32\n",
                                 "max_read = 32\ntiming = { guard = 5 }\n", "bad.toml"))


# == the ZLAC8015D hub servo (left channel) beside the Leadshine and a seed drive =============

ZLAC = ROOT / "configs" / "drives" / "zlac8015d.toml"


async def test_foreign_descriptions_share_a_machine_with_a_seed_drive() -> None:
    """The Leadshine and the ZLAC8015D (status decoded from speed and a tracked target: the
    drive reports neither enabled nor running) on one simulated line with the NT86: a
    group move, then every axis jogging and an emergency stop, judged by the twins."""
    def axis(address: int, drive: str | Path, ppr: int) -> dict[str, Any]:
        return {"line": "rs485", "address": address, "drive": str(drive),
                "pulses_per_rev": ppr, "units_per_rev": 10.0, "speed": 50.0, "accel": 500.0,
                "decel": 500.0, "limits": [-100.0, 300.0],
                "poll": {"moving": 0.01, "idle": 0.05}}

    cfg = {"name": "foreign-mixed",
           "lines": {"rs485": {"port": "sim://foreign-mixed", "settings": "115200 8N1",
                               "timeout": 0.1}},
           "axes": {"x": axis(2, "NT86", 4000), "l": axis(3, LEADSHINE, 10000),
                    "z": axis(4, ZLAC, 16384)}}
    with anyio.fail_after(30):
        async with open_machine(cfg) as m:
            for a in m.axes.values():
                await a.enable()
            await m.group("x", "l", "z").move_to({"x": 40.0, "l": 25.0, "z": -12.5})
            twins = m.sim_drives
            assert [twins[n].position() for n in ("x", "l", "z")] == [16000, 25000, -20480]
            assert all(m.axes[n].state is AxisState.STANDSTILL for n in ("x", "l", "z"))
            for a in m.axes.values():
                await a.jog(5.0, watchdog=None)
            await until(lambda: all(t.is_moving() for t in twins.values()))
            async with anyio.create_task_group() as tg:
                for a in m.axes.values():
                    tg.start_soon(a.halt_now)
            for name, twin in twins.items():
                assert not twin.is_moving(), name


def test_the_zlac8015d_description_passes_its_trial() -> None:
    out = drive_try(ZLAC)
    assert "11 passed, 0 failed, 1 skipped" in out
    assert "home             skip  the ZLAC8015D-L drive cannot home" in out


EDGE_START = """
[drive]
family = "EDGE-START"

[link]
addresses = [1, 1]

[constants]
START = 0x0001

[units.pulses_per_rev]
default = 1000

[registers.status]
address = 0
access = "R"
bits.RUNNING = { bit = 0, means = "moving" }

[registers.position]
address = 1
words = 2
signed = true
unit = "pulses"
access = "R"
means = "position"

[registers.distance]
address = 3
words = 2
signed = true
unit = "pulses"

[registers.speed]
address = 5
unit = "rpm"
min = 1
max = 3000

[registers.accel]
address = 6
unit = "r/s²"
min = 1
max = 1000

[registers.control]
address = 7
name = "control word (bit 0: start on its 0 -> 1 edge)"

[procedures.move_relative]
steps = [
  { write = { distance = "distance", speed = "speed", accel = "accel" }, block = true },
  { write = { control = 0 } },
  { write = { control = "START" }, idempotent = false },
]

[[twin.on_write]]
register = "control"
when = "value & START and not previous & START"
do = "move_relative"
distance = "distance"
speed = "speed"
accel = "accel"
decel = "accel"
"""


async def test_a_start_on_a_rising_edge_and_a_twin_that_sees_it(tmp_path: Path) -> None:
    """``previous`` in ``[twin]``: the word before the write, so a twin starts only on the
    0 -> 1 edge its manual says; a description that forgets to lower the bit first moves
    once and then never again."""
    async def moves(text: str) -> list[int]:
        path = tmp_path / "edge.toml"
        path.write_text(text, encoding="utf-8")
        desc = load_description(path)
        twin = described_twin(desc)(1, FAST)
        async with sim_bus([twin], FAST) as (_, bus):
            profile = profile_class(desc)(bus.slave(1))
            out = []
            for _ in range(2):
                await profile.move_relative(500, MoveParams(600, 1000, 1000))
                await until_at(twin, 0)
                out.append(twin.position())
            return out

    assert await moves(EDGE_START) == [500, 1000]
    assert await moves(EDGE_START.replace('  { write = { control = 0 } },\n', '')) == [500, 500]
    with pytest.raises(ConfigError, match=r"procedures\.move_relative\.steps\[1\]\.write\."
                                          r"control: 'previous' uses 'previous'"):
        bad = tmp_path / "bad.toml"
        bad.write_text(EDGE_START.replace("{ control = 0 }", '{ control = "previous" }'),
                       encoding="utf-8")
        load_description(bad)


async def test_a_manual_in_4xxxx_numbering_is_written_as_it_prints(tmp_path: Path) -> None:
    """``link.register_base = 40001``: the addresses are the manual's register numbers and
    the frames are those of the 0-based file; a number below the base is named."""
    def numbered(text: str) -> str:
        text = text.replace("[link]\n", "[link]\nregister_base = 40001\n")
        return re.sub(r"^address = (\d+)$", lambda m: f"address = {40001 + int(m[1])}", text,
                      flags=re.M)

    frames = []
    for i, text in enumerate((EDGE_START, numbered(EDGE_START))):
        path = tmp_path / f"d{i}.toml"
        path.write_text(text, encoding="utf-8")
        desc = load_description(path)
        twin = described_twin(desc)(1, FAST)
        async with sim_bus([twin], FAST) as (wire, bus):
            await profile_class(desc)(bus.slave(1)).move_relative(
                -700, MoveParams(600, 1000, 1000))
            frames.append([f.data for f in wire.requests()])
    assert frames[0] == frames[1] and len(frames[0]) == 3
    assert frames[1][0].hex(" ").startswith("01 10 00 03 00 04")  # 40004 is address 3
    bad = tmp_path / "bad.toml"
    bad.write_text(numbered(EDGE_START).replace("address = 40008", "address = 7"),
                   encoding="utf-8")
    with pytest.raises(ConfigError, match=r"bad\.toml: registers\.control\.address: 7 is "
                                          r"below the first register, 40001"):
        load_description(bad)


def acknowledging(text: str) -> str:
    """EDGE_START as a drive that clears its control word when it takes a command, and a
    procedure that waits for that acknowledge."""
    text = text.replace(
        '  { write = { control = 0 } },\n'
        '  { write = { control = "START" }, idempotent = false },\n',
        '  { write = { control = "START" }, idempotent = false },\n'
        '  { wait = "control == 0", read = ["control"], timeout = 0.5 },\n')
    return text.replace('when = "value & START and not previous & START"',
                        'when = "value & START"\nset = { control = 0 }')


async def test_an_acknowledge_handshake_and_a_wait_that_times_out(tmp_path: Path) -> None:
    """``[twin]`` triggers ``set`` what the drive writes back (an acknowledge); a ``wait``
    that never holds is a typed error naming its condition, not a bare timeout."""
    async def move(text: str) -> int:
        path = tmp_path / "ack.toml"
        path.write_text(text, encoding="utf-8")
        desc = load_description(path)
        twin = described_twin(desc)(1, FAST)
        async with sim_bus([twin], FAST) as (wire, bus):
            await profile_class(desc)(bus.slave(1)).move_relative(
                300, MoveParams(600, 1000, 1000))
            assert [f.data[1] for f in wire.requests()] == [16, 6, 3]  # block, start, ack
            await until_at(twin, 0)
            return twin.position()

    text = acknowledging(EDGE_START)
    assert await move(text) == 300
    with pytest.raises(StateError, match=r"EDGE-START: move_relative: 'control == 0' did not "
                                         r"hold within 0\.5 s"):
        await move(text.replace("set = { control = 0 }", ""))
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("set = { control = 0 }", "set = { contrl = 0 }"),
                   encoding="utf-8")
    with pytest.raises(ConfigError, match=r"twin\.on_write\[0\]\.set\.contrl: no register"):
        load_description(bad)


async def test_blocks_are_cut_to_the_drives_max_write(tmp_path: Path) -> None:
    """``link.max_write``: a block longer than the drive takes goes in several FC16, never
    splitting a 32-bit value; the twin refuses a longer write as the drive would."""
    desc = load_description(variant(tmp_path, "max_read = 32\n", "max_read = 32\nmax_write = 2\n"))
    twin = described_twin(desc)(1, FAST)
    async with sim_bus([twin], FAST) as (wire, bus):
        profile = profile_class(desc)(bus.slave(1))
        await profile.run("enable")
        wire.clear_log()
        await profile.move_absolute(12345, MoveParams(300, 50, 50))
        writes = [(f.data[1], int.from_bytes(f.data[2:4], "big"),
                   int.from_bytes(f.data[4:6], "big")) for f in wire.requests()]
        # mode alone (mode + the 32-bit position would be 3), the position, speed and
        # acceleration, deceleration; then the trigger
        assert writes == [(16, PR_MODE, 1), (16, PR_POS_HI, 2), (16, PR_SPEED, 2),
                          (16, PR_DEC, 1), (6, TRIGGER, 0x10)]
        assert await until_at(twin, 12345)
        with pytest.raises(ModbusException) as exc:
            await bus.slave(1).write_registers(PR_MODE, [1, 0, 0])
        assert exc.value.code == 3


async def test_a_cia402_move_waits_for_the_drive_to_change_modes(tmp_path: Path) -> None:
    """A drive that takes 50 ms to change modes loses a set-point sent before it has: with
    its mode display (6061) described, the engine waits for it."""
    text = KINCO.read_text(encoding="utf-8").replace("[registers.pos_actual]", """\
[registers.operation_mode_display]
address = 0x3600
object = "6061"
signed = true
access = "R"

[registers.pos_actual]""")
    described = tmp_path / "kinco_display.toml"
    described.write_text(text, encoding="utf-8")
    drive = Kinco(mode_lag=0.05)
    with anyio.fail_after(30):
        async with served(drive, K_READ_ONLY) as line, \
                open_machine(machine(line, described)) as m:
            a = m.axes["a"]
            await a.enable()
            await a.move_to(12.5)
            assert drive.position == 12500 and drive.set_points == [(0x3F, 12500)]
            await a.jog(-2.0, watchdog=None)  # a move to the soft limit, same mode
            await until(lambda: drive.vel < 0)
            await a.stop()


def test_drive_check_warns_of_addresses_that_look_4xxxx_numbered(tmp_path: Path) -> None:
    numbered = re.sub(r"^address = (\d+)$", lambda m: f"address = {40001 + int(m[1])}",
                      EDGE_START, flags=re.M)
    path = tmp_path / "edge4x.toml"
    path.write_text(numbered, encoding="utf-8")
    assert "every register address is in 40001..49999 (40001...40008): if the manual " \
        "numbers registers 4xxxx, set [link] register_base = 40001" in drive("check", path)
    path.write_text(numbered.replace("[link]\n", "[link]\nregister_base = 40001\n"),
                    encoding="utf-8")
    out = drive("check", path)
    assert "40001..49999" not in out
    assert "FC03 0 (0x0000)" in out  # the status poll at PDU address 0


# == coils and discrete inputs (FC01, FC02, FC05) ===============================================

COIL_DRIVE = """
[drive]
family = "COIL-DRIVE"
description = "a servo switched on by a coil, its state in discrete inputs"

[link]
functions = [1, 2, 3, 5, 6, 16]

[units.pulses_per_rev]
default = 1000

[registers.servo_on]
address = 0x0060
coil = true
name = "SRV-ON"

[registers.start]
address = 0x0120
coil = true
name = "STB (block start on its rising edge)"

[registers.ready]
address = 0x0040
discrete = true
access = "R"
means = "enabled"

[registers.busy]
address = 0x0041
discrete = true
access = "R"
means = "moving"

[registers.fault]
address = 0x0042
discrete = true
access = "R"
means = "alarm"

[registers.distance]
address = 0x4600
words = 2
signed = true
unit = "pulses"

[registers.speed]
address = 0x4602
unit = "rpm"
min = 1
max = 5000

[registers.accel]
address = 0x4603
unit = "r/s²"
min = 1
max = 10000

[registers.position]
address = 0x4800
words = 2
signed = true
unit = "pulses"
access = "R"
means = "position"

[procedures.enable]
steps = [{ write = { servo_on = 1 } }]

[procedures.disable]
steps = [{ write = { servo_on = 0 } }]

[procedures.move_relative]
steps = [
  { write = { distance = "distance", speed = "speed", accel = "accel" }, block = true },
  { write = { start = 0 } },
  { write = { start = 1 }, idempotent = false },
]

[twin]
enabled = false

[[twin.on_write]]
register = "servo_on"
when = "value == 1"
do = "enable"

[[twin.on_write]]
register = "servo_on"
when = "value == 0"
do = "disable"

[[twin.on_write]]
register = "start"
when = "value == 1 and previous == 0"
do = "move_relative"
distance = "distance"
speed = "speed"
accel = "accel"
decel = "accel"
"""


async def test_coils_and_discrete_inputs(tmp_path: Path) -> None:
    """A drive switched on by a coil (FC05), started by a coil's rising edge, its state in
    discrete inputs (FC02): the engine reads and writes each address space with its own
    function codes, the twin answers them, and the checks name what a coil cannot be."""
    path = tmp_path / "coil.toml"
    path.write_text(COIL_DRIVE, encoding="utf-8")
    desc = load_description(path)
    twin = described_twin(desc)(1, FAST)
    async with sim_bus([twin], FAST) as (wire, bus):
        profile = profile_class(desc)(bus.slave(1))
        st = await profile.read_status()
        assert not st.enabled and not st.moving and st.position == 0
        assert {f.data[1] for f in wire.requests()} == {2, 3}  # FC02 and FC03, no FC01
        await profile.enable()
        assert wire.requests()[-1].data[1:6].hex(" ") == "05 00 60 ff 00"
        assert (await profile.read_status()).enabled and twin.enabled
        wire.clear_log()
        # (half a second: a status read after the start sees it moving on a busy machine)
        await profile.move_relative(-400, MoveParams(60, 10, 10))
        assert [f.data[1] for f in wire.requests()] == [16, 5, 5]
        assert (await profile.read_status()).moving
        assert await until_at(twin, -400)
        st = await profile.read_status()
        assert st.position == -400 and not st.moving
        await profile.disable()
        assert not twin.enabled and wire.requests()[-1].data[1:6].hex(" ") == "05 00 60 00 00"
        # the twin answers coils only where the description has them
        with pytest.raises(ModbusException) as exc:
            await bus.slave(1).read_coils(0x0061, 1)
        assert exc.value.code == 2
        assert await bus.slave(1).read_coils(0x0060, 1) == [0]
    for old, new, problem in (
        ("coil = true\nname = \"SRV-ON\"", "coil = true\nwords = 2\nname = \"SRV-ON\"",
         r"registers\.servo_on: .*a coil or discrete input is one bit"),
        ("functions = [1, 2, 3, 5, 6, 16]", "functions = [2, 3, 5, 6, 16]",
         r"link\.functions: coils need function code 1"),
        ("[procedures.enable]\nsteps = [{ write = { servo_on = 1 } }]",
         '[procedures.enable]\nsteps = [{ modify = "servo_on", set_bits = 1 }]',
         r"procedures\.enable\.steps\[0\]\.modify: servo_on is a coil"),
    ):
        path.write_text(COIL_DRIVE.replace(old, new), encoding="utf-8")
        with pytest.raises(ConfigError, match=problem):
            load_description(path)


async def test_coil_and_discrete_input_frames_against_pymodbus() -> None:
    """The FC01/FC02/FC05 frames against a third-party server (pymodbus on loopback)."""
    from pymodbus.simulator import DataType, SimData, SimDevice

    from drivebus import Bus
    from drivebus.line.tcp import TcpLine

    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    blocks = ([SimData(0, count=32, values=False, datatype=DataType.BITS)],
              [SimData(0, values=[True, False, True] + [False] * 13, datatype=DataType.BITS)],
              [SimData(0, values=[0], datatype=DataType.REGISTERS)],
              [SimData(0, values=[0], datatype=DataType.REGISTERS)])
    server = ModbusTcpServer([SimDevice(1, simdata=blocks)], address=(HOST, 0))
    await server.serve_forever(background=True)
    try:
        port = server.transport.sockets[0].getsockname()[1]
        async with Bus(TcpLine(HOST, port), timeout=1.0) as bus:
            s = bus.slave(1)
            assert await s.read_discrete_inputs(0, 3) == [1, 0, 1]
            await s.write_coil(5, True)
            assert await s.read_coils(0, 10) == [0, 0, 0, 0, 0, 1, 0, 0, 0, 0]
            await s.write_coil(5, False)
            assert await s.read_coils(4, 3) == [0, 0, 0]
    finally:
        await server.shutdown()
