"""Drives whose manuals stress the description format, described from their public manuals
only and driven through the public API against INDEPENDENT emulators (the hidden test of
issue 22 played again).

* The Delta ASDA-B2 servo in PR (procedure) mode (configs/drives/delta_asda_b2.toml): its
  parameters P0-xx..P6-xx at addresses computed from the group and number
  (``[link] parameter_numbers``), 32-bit parameters low word first, PR#1's definition and
  data started by the PR trigger P5-07, homing by PR#0 (P5-04), servo on and alarm reset
  through software digital inputs (P3-06, P4-07), at most 10 registers a request, 10 ms of
  silence around each frame, a line format of 8N2.

The emulator is a pymodbus server (RTU over a pty null-modem, or Modbus TCP on loopback)
whose behaviour is written from the manual's words with a kinematic of its own: nothing of
``drivebus.sim`` is used. It refuses what the manual says the drive refuses (more than 10
registers a request: exception 03; addresses it lacks: 02; writes to read-only monitors).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import anyio
import pytest

from drivebus import AxisState, open_machine
from drivebus.drives.description import load_description
from drivebus.errors import ConfigError, LimitViolation, StateError
from pymodbus_servers import PYMODBUS
from test_foreign_drives import drive, register_device, serving, until
from test_foreign_drives_more import Shaft, _s32

ROOT = Path(__file__).resolve().parents[1]
DELTA = ROOT / "configs" / "drives" / "delta_asda_b2.toml"

pytestmark = pytest.mark.skipif(PYMODBUS < (3, 13), reason="SimDevice actions: pymodbus 3.13+")


# == Delta ASDA-B2, PR mode (from the manual's parameter chapter) ============================


def param(group: int, number: int) -> int:
    """A parameter's Modbus address, as the manual prints it: 0304H for P3-02."""
    return group * 0x100 + number * 2


ALE, MON1, SEL1, CTL = param(0, 1), param(0, 9), param(0, 17), param(1, 1)
DI1, DI2 = param(2, 10), param(2, 11)
DO_FUNCS = [param(2, n) for n in range(18, 23)]
SDI_SRC, ITST, MOT = param(3, 6), param(4, 7), param(4, 9)
HMOV, HSPD1, HSPD2, PRCM = param(5, 4), param(5, 5), param(5, 6), param(5, 7)
AC0, AC1, POV0 = param(5, 20), param(5, 21), param(5, 60)
ODAT, PDEF1, PDAT1 = param(6, 1), param(6, 2), param(6, 3)
DELTA_PARAMS = [ALE, MON1, SEL1, CTL, DI1, DI2, *DO_FUNCS, SDI_SRC, ITST, MOT, HMOV, HSPD1,
                HSPD2, PRCM, AC0, AC1, POV0, ODAT, PDEF1, PDAT1]
DELTA_READ_ONLY = {a + i for a in (ALE, MON1, MOT) for i in (0, 1)}
# DI and DO function codes (the low byte; 0x01xx: normally open)
F_SON, F_ARST = 0x01, 0x02
O_SON, O_ZSPD, O_HOME, O_ALRM = 0x02, 0x03, 0x09, 0x07
PUU_PER_REV = 100000
NEGATIVE_LIMIT = -300000.0  # PUU: where the negative limit switch (NL) sits (-30 mm)
POSITIVE_LIMIT = 2000000.0
ALARM_RESETTABLE = {0x06, 0x09, 0x13, 0x14, 0x15}


def puu_s(rpm_tenths: int) -> float:
    """PUU/s of a speed in 0.1 r/min."""
    return rpm_tenths / 10 / 60 * PUU_PER_REV


def rate(ms: int) -> float:
    """PUU/s² of an acceleration time, ms from 0 to 3000 r/min."""
    return 3000 / 60 * PUU_PER_REV / (max(ms, 1) / 1000)


@dataclass
class DeltaB2(Shaft):
    """An ASDA-B2 in PR mode as its manual says: P5-07 = n runs PR#n (here PR#1: its
    definition P6-02 and data P6-03), 0 homes by P5-04, 1000 stops with the path's
    deceleration time; a position path with INS interrupts the running one. Digital inputs
    come from the terminals or, where P3-06 says, from P4-07: SON switches the servo on,
    ARST resets a resettable alarm on its rising edge. P4-09 shows the outputs P2-18..P2-22
    assign (SON, ZSPD, HOME, ALRM...). Every parameter is two registers, low word first;
    more than 10 registers a request is refused with exception 03."""

    regs: dict[int, int] = field(default_factory=dict)
    servo_on: bool = False
    alarm: int = 0
    homed: bool = False
    homing: bool = False
    writes: list[tuple[int, list[int]]] = field(default_factory=list)
    requests: list[tuple[int, int, int]] = field(default_factory=list)
    """(function, address, count) of every request the emulator served."""

    def __post_init__(self) -> None:
        for a in DELTA_PARAMS:
            self.regs[a], self.regs[a + 1] = 0, 0
        for a, v in ((CTL, 0x0001), (DI1, 0x0101), (DI2, 0x0104), (AC0, 200), (AC1, 300),
                     (POV0, 200), (HSPD1, 1000), (HSPD2, 200),
                     *zip(DO_FUNCS, (0x0101, 0x0103, 0x0109, 0x0105, 0x0007), strict=True)):
            self.regs[a] = v

    def get(self, a: int) -> int:
        return _s32(self.regs[a + 1], self.regs[a])  # low word first

    def di(self, function: int) -> bool:
        """Whether the input assigned ``function`` is on (software or terminal: the
        terminals are all open here)."""
        sdi, source = self.regs[ITST], self.regs[SDI_SRC]
        for n, a in enumerate((DI1, DI2)):
            if self.regs[a] & 0xFF == function and source >> n & 1:
                return bool(sdi >> n & 1)
        return False

    def raise_alarm(self, code: int) -> None:
        self.alarm, self.servo_on, self.homing = code, False, False
        self.settle(self.pos)  # servo off: the dynamic brake stops the motor

    def landed(self) -> None:
        if self.homing:
            self.homing, self.homed = False, True

    def _tick(self) -> None:
        super()._tick()
        if self.homing and self.pos <= NEGATIVE_LIMIT:  # NL reached: that is the origin
            self.homing, self.homed = False, True
            self.settle(float(self.get(ODAT)))
        if self.moving and not self.homing and not NEGATIVE_LIMIT <= self.pos <= POSITIVE_LIMIT:
            self.raise_alarm(0x14 if self.pos < 0 else 0x15)

    def inputs(self, before_son: bool, before_arst: bool) -> None:
        son, arst = self.di(F_SON), self.di(F_ARST)
        if arst and not before_arst and self.alarm in ALARM_RESETTABLE:
            self.alarm = 0
        if son and not self.alarm:
            self.servo_on = True
        elif not son and before_son:
            self.servo_on = False
            self.settle(self.pos)

    def trigger(self, value: int) -> None:
        if value == 1000:
            if self.moving:
                self.homing = False
                self.goal, self.dec = "brake", rate(self.decel_index())
            return
        if not self.servo_on or self.alarm:
            return
        acc_i, dec_i = self.regs[PDEF1] >> 8 & 0xF, self.regs[PDEF1] >> 12 & 0xF
        acc, dec = rate(self.regs[AC0 + 2 * acc_i]), rate(self.regs[AC0 + 2 * dec_i])
        if value == 0:
            method = self.regs[HMOV] & 0xF
            if method == 1:  # reverse to NL at the first homing speed
                self.homing, self.homed = True, False
                self.goal, self.speed, self.acc, self.dec = \
                    "run", -puu_s(self.regs[HSPD1]), acc, dec
            return
        if value != 1 or (self.moving and not self.regs[PDEF1] & 0x80):
            return  # another path, or one without INS while a path runs
        kind, data = self.regs[PDEF1] & 0xF, self.get(PDAT1)
        if kind == 1:  # SPEED: the data is the target speed in 0.1 r/min
            self.goal, self.speed, self.acc, self.dec = "run", puu_s(data), acc, dec
        elif kind == 2:  # SINGLE: absolute, or relative to the present command
            base = (self.target if self.goal == "to" else self.pos) \
                if self.regs[PDEF1] & 0x30 == 0x10 else 0.0
            speed = puu_s(self.regs[POV0 + 2 * (self.regs[PDEF1 + 1] & 0xF)])
            self.goal, self.target, self.vmax, self.acc, self.dec = \
                "to", base + data, speed, acc, dec

    def decel_index(self) -> int:
        return self.regs[AC0 + 2 * (self.regs[PDEF1] >> 12 & 0xF)]

    def outputs(self) -> int:
        state = {O_SON: self.servo_on, O_ZSPD: not self.moving, O_HOME: self.homed,
                 O_ALRM: bool(self.alarm)}
        return sum(1 << n for n, a in enumerate(DO_FUNCS) if state.get(self.regs[a] & 0xFF))

    async def action(self, function: int, start: int, address: int, count: int,
                     registers: list[int], values: Any) -> Any:
        """pymodbus's hook on every access: at most 10 registers; writes act."""
        from pymodbus.constants import ExcCodes

        self.requests.append((function, address, count))
        if count > 10:
            return ExcCodes.ILLEGAL_VALUE  # "the maximum allowable data ... is 10"
        self.advance(time.monotonic())
        if values is not None:
            son, arst = self.di(F_SON), self.di(F_ARST)
            self.writes.append((address, list(values)))
            for i, v in enumerate(values):
                self.regs[address + i] = v
            span = range(address, address + len(values))
            if ITST in span or SDI_SRC in span:
                self.inputs(son, arst)
            if PRCM in span:
                self.trigger(self.regs[PRCM])
        p = round(self.pos) & 0xFFFFFFFF
        self.regs.update({ALE: self.alarm, MOT: self.outputs(), MON1: p & 0xFFFF,
                          MON1 + 1: p >> 16})
        for a, v in self.regs.items():
            registers[a - start] = v
        return None


def delta_machine(line: dict[str, Any], limits: bool = True) -> dict[str, Any]:
    """One axis on the emulated ASDA-B2: 100000 PUU per revolution, 10 mm per revolution."""
    axis: dict[str, Any] = {
        "line": "bus", "address": 1, "drive": str(DELTA), "pulses_per_rev": PUU_PER_REV,
        "units_per_rev": 10.0, "unit": "mm", "speed": 60.0, "accel": 600.0, "decel": 600.0,
        "poll": {"moving": 0.01, "idle": 0.05},
        "homing": {"method": "negative_limit", "speed": 30.0, "creep": 5.0, "accel": 600.0},
    }
    if limits:
        axis["limits"] = [-20.0, 200.0]
    return {"name": "delta", "lines": {"bus": line}, "axes": {"a": axis}}


def delta_served(dv: DeltaB2, transport: str = "rtu") -> Any:
    return serving(register_device(dv.regs, dv.action, DELTA_READ_ONLY), transport,
                   (115200, "N", 2))


async def first_alarm(axis: Any) -> Any:
    """The first status the axis shows with an alarm (bounded)."""
    with anyio.fail_after(5):
        async for st in axis.watch():
            if st.alarm:
                return st
    raise AssertionError("no alarm")


@pytest.mark.parametrize("transport", ["rtu", "tcp"])
async def test_the_delta_asda_b2_description_drives_an_independent_emulator(
        transport: str) -> None:
    dv = DeltaB2()
    with anyio.fail_after(60):
        async with delta_served(dv, transport) as line, open_machine(delta_machine(line)) as m:
            a = m.axes["a"]
            assert not (await a.refresh()).enabled
            await a.enable()
            assert dv.servo_on and dv.writes[-1] == (ITST, [0x0001])
            # setup (before the first command): DI1/DI2 handed to P4-07, the outputs
            # assigned; what already holds is not written again (EEPROM)
            assert dv.regs[SDI_SRC] == 0x0003 and dv.regs[DI2] == 0x0102
            assert [dv.regs[x] for x in DO_FUNCS] == [0x0102, 0x0103, 0x0109, 0x0105, 0x0107]
            assert (DI1, [0x0101]) not in dv.writes and (SEL1, [0]) not in dv.writes
            await a.move_to(20.0)
            assert round(dv.pos) == 200000 and a.position == 20.0
            assert a.state is AxisState.STANDSTILL
            # ramps 0..3000 r/min: 600 mm/s² = 60 r/s² -> 833 ms; 360 r/min in 0.1 r/min;
            # PR#1 = SINGLE | INS | DEC #1, its data 200000 PUU low word first; then P5-07 = 1
            assert (AC0, [833]) in dv.writes and (POV0, [3600]) in dv.writes
            assert dv.writes[-2:] == [(PDEF1, [0x1082, 0, 200000 & 0xFFFF, 200000 >> 16]),
                                      (PRCM, [1])]
            await a.move_by(-25.0)
            assert round(dv.pos) == -50000 and dv.writes[-2][1][0] == 0x1092
            # A jog within soft limits is a path to the limit; stop is P5-07 = 1000.
            await a.jog(-5.0, watchdog=None)
            await until(lambda: dv.vel < 0)
            assert dv.target == -200000
            await a.stop()
            assert not dv.moving and dv.writes[-1] == (PRCM, [1000])
            # Homing: PR#0 (P5-04 = 0x21: reverse to NL, no Z), 3 r/min = 30 in 0.1 r/min
            await a.home()
            assert dv.homed and round(dv.pos) == 0 and a.homed and a.position == 0.0
            assert (HMOV, [0x0021]) in dv.writes and dv.writes[-1] == (PRCM, [0])
            # Soft limits: nothing is written for a move beyond them.
            sent = len(dv.writes)
            with pytest.raises(LimitViolation):
                await a.move_to(500.0)
            assert len(dv.writes) == sent
            # An alarm with the manual's text; ARST (software DI2) resets it.
            await a.jog(5.0, watchdog=None)
            await until(lambda: dv.vel > 0)
            dv.raise_alarm(0x09)
            st = await first_alarm(a)
            assert st.alarm_code == 9 and st.alarm_text == "position control error overflow"
            with pytest.raises(StateError, match=r"drive alarm 9: position control error"):
                await a.move_to(10.0)
            await a.reset()
            assert dv.alarm == 0 and (ITST, [0x0002]) in dv.writes
            # The emergency stop: the shortest deceleration time, then the PR stop.
            await a.enable()
            await a.jog(5.0, watchdog=None)
            await until(lambda: dv.vel > 0)
            await a.halt_now()
            await until(lambda: not dv.moving, timeout=2.0)
            assert dv.writes[-2:] == [(AC1, [1]), (PRCM, [1000])]
            await a.disable()
            assert not dv.servo_on and not (await a.refresh()).enabled
    assert all(count <= 10 for _, _, count in dv.requests)


async def test_the_delta_asda_b2_runs_a_speed_path() -> None:
    """Without soft limits a jog is a speed path (TYPE 1): its data the signed speed in
    0.1 r/min; the stop decelerates with the path's deceleration time."""
    dv = DeltaB2()
    with anyio.fail_after(60):
        async with delta_served(dv, "tcp") as line, \
                open_machine(delta_machine(line, limits=False)) as m:
            a = m.axes["a"]
            await a.enable()
            await a.jog(-20.0, watchdog=None)
            await until(lambda: dv.vel == -puu_s(1200))
            assert dv.regs[PDEF1] == 0x1081 and dv.get(PDAT1) == -1200
            await a.stop(decel=100.0)
            assert not dv.moving and dv.writes[-2:] == [(AC1, [5000]), (PRCM, [1000])]


async def test_the_delta_asda_b2_setup_refuses_a_drive_not_in_pr_mode() -> None:
    """P1-01 takes a new mode only at power-up: setup says so and switches nothing."""
    dv = DeltaB2()
    dv.regs[CTL] = 0x0000  # position (PT) mode
    with anyio.fail_after(30):
        async with delta_served(dv, "tcp") as line:
            with pytest.raises(StateError, match=r"P1-01 is 0x0000: set 0x0001 \(PR mode\)"):
                async with open_machine(delta_machine(line)) as m:
                    await m.axes["a"].enable()
    assert not any(a == SDI_SRC for a, _ in dv.writes)


def test_parameter_numbers_give_addresses_and_bad_ones_are_named(tmp_path: Path) -> None:
    desc = load_description(DELTA)
    assert desc.regs["trigger"].d.address == 0x050E and desc.regs["sdi"].d.address == 0x040E
    assert desc.regs["trigger"].d.name.startswith("P5-07")
    text = DELTA.read_text(encoding="utf-8")
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('address = "P5-07"', 'address = "P5.07"'), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"bad\.toml: registers\.trigger\.address: 'P5\.07' "
                                          r"is not a parameter number of the form"):
        load_description(bad)
    bad.write_text(text.replace("parameter_numbers = {", "# {"), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"bad\.toml: registers\.\w+\.address: 'P\d-\d\d' is "
                                          r"not an address: .*\[link\] parameter_numbers"):
        load_description(bad)
    bad.write_text(text.replace('"group * 0x100 + number * 2"', '"grp * 0x100"'),
                   encoding="utf-8")
    with pytest.raises(ConfigError, match=r"link\.parameter_numbers.*grp is not a part"):
        load_description(bad)


def test_the_delta_asda_b2_description_passes_its_check() -> None:
    out = drive("check", DELTA)
    assert "DELTA-ASDA-B2 (command engine)" in out and "FC03 1294" not in out


def test_the_delta_asda_b2_description_passes_its_trial() -> None:
    """``drivebus drive try``: the description against the generic twin of its ``[twin]``
    section (written from the parameter chapter apart from the procedures)."""
    assert "12 passed, 0 failed, 0 skipped" in drive("try", DELTA)


async def test_the_delta_asda_b2_shares_a_machine_with_a_seed_drive() -> None:
    """The NT86 (simulated line) and the ASDA-B2 (emulator on Modbus TCP) in one machine:
    a group move, then both jogging and an emergency stop, judged by the twin and the
    emulator."""
    dv = DeltaB2()
    with anyio.fail_after(60):
        async with delta_served(dv, "tcp") as line:
            cfg = delta_machine(line)
            cfg["name"] = "delta-mixed"
            cfg["lines"]["rs485"] = {"port": "sim://delta-mixed", "settings": "115200 8N1",
                                     "timeout": 0.1}
            cfg["axes"]["x"] = {"line": "rs485", "address": 1, "drive": "NT86",
                                "pulses_per_rev": 4000, "units_per_rev": 10.0, "speed": 50.0,
                                "accel": 500.0, "decel": 500.0, "limits": [-100.0, 300.0],
                                "poll": {"moving": 0.01, "idle": 0.05}}
            async with open_machine(cfg) as m:
                for a in m.axes.values():
                    await a.enable()
                await m.group("x", "a").move_to({"x": 40.0, "a": 25.0})
                nt86 = m.sim_drives["x"]
                assert (nt86.position(), round(dv.pos)) == (16000, 250000)
                assert all(a.state is AxisState.STANDSTILL for a in m.axes.values())
                for a in m.axes.values():
                    await a.jog(5.0, watchdog=None)
                await until(lambda: nt86.is_moving() and dv.vel > 0)
                async with anyio.create_task_group() as tg:
                    for a in m.axes.values():
                        tg.start_soon(a.halt_now)
                assert not nt86.is_moving() and not dv.moving
