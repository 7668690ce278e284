"""A homing is judged by what the drive reports after it started (issue 31, items 2 and 3),
on the independent Kinco FD emulator of tests/test_foreign_drives.py (pymodbus, Modbus RTU
over a pty, written from the manual; nothing of ``drivebus.sim``).

* Item 2: a drive that reports a homing error (CiA 402 homing mode, statusword bit 13)
  from the first poll after the start ends ``home()`` at once with a typed error that names
  it, not a ``MotionTimeout`` after the homing timeout.
* Item 3: only a status whose request left after the homing start's reply may judge the
  homing. The drive takes 130 ms to answer the mode write (a legal reply time), so a poll
  that read the statusword before the start ("not started": target reached, no attained)
  finishes after it; ``home()`` must still complete when the drive reports "attained".
  The description here has no homed flag of its own (the Kinco's bit 15 is left out), so
  the homing record alone decides.

Both failed before the fix of the axis and the engines (DriveStatus.homing_error and
requested_at) for the reason each states, bounded well under a minute: item 2 waited out
the homing timeout (here cut at 5 s), item 3 timed out while the drive showed attained.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import anyio
import pytest

from drivebus import open_machine
from drivebus.errors import DrivebusError, MotionAborted, MotionTimeout
from pymodbus_servers import PYMODBUS
from test_foreign_drives import K_MODE, K_READ_ONLY, K_SW, KINCO, Kinco, machine, served

pytestmark = pytest.mark.skipif(PYMODBUS < (3, 13), reason="SimDevice actions: pymodbus 3.13+")

MODE_REPLY = 0.13
"""s the slow drive takes to answer a write of modes of operation (6060, 0x3500)."""


class SlowModeKinco(Kinco):
    """The Kinco FD emulator, answering a mode write only after ``MODE_REPLY`` seconds (the
    write acts at once; its reply is late). ``answered`` is set each time it answers a read
    of the statusword (0x3200)."""

    def __init__(self) -> None:
        super().__init__()
        self.answered = anyio.Event()

    async def action(self, function: int, start: int, address: int, count: int,
                     registers: list[int], values: Any) -> Any:
        result = await super().action(function, start, address, count, registers, values)
        span = range(address, address + count)
        if values is not None and K_MODE in span:
            await anyio.sleep(MODE_REPLY)
        elif values is None and K_SW in span:
            self.answered.set()
        return result


def without_the_homed_bit(tmp_path: Path) -> Path:
    """The Kinco FD description without statusword bit 15 (home found)."""
    text = KINCO.read_text(encoding="utf-8")
    line = next(ln for ln in text.splitlines() if ln.startswith("bits.HOME_FOUND"))
    path = tmp_path / "kinco_no_home_flag.toml"
    path.write_text(text.replace(line + "\n", ""), encoding="utf-8")
    return path


async def test_a_homing_error_from_the_first_poll_ends_home_at_once() -> None:
    """The emulator has no home switch to home on (method 24): homing error (statusword bit
    13) from the first status after the start. home() raises within 5 s, well inside the
    30 s homing timeout, an error naming the homing error (it waited the timeout)."""
    drive = Kinco()
    with anyio.fail_after(50):
        async with served(drive, K_READ_ONLY) as line:
            cfg = machine(line, KINCO)
            cfg["axes"]["a"]["homing"].update(method="home_switch_forward", timeout=30.0)
            async with open_machine(cfg) as m:
                a = m.axes["a"]
                await a.enable()
                try:
                    with anyio.fail_after(5), pytest.raises(DrivebusError) as info:
                        await a.home()
                except TimeoutError:
                    assert drive.homing_error, "the emulator did not report a homing error"
                    raise
                assert drive.homing_error and drive.statusword() & 0x2000
                assert not isinstance(info.value, MotionTimeout), info.value
                assert re.search(r"homing.*(error|fail)", str(info.value), re.I), info.value
                assert not a.homed


async def test_a_status_read_before_the_homing_start_does_not_decide_it(
        tmp_path: Path) -> None:
    """A homing stopped half-way leaves the drive in homing mode, interrupted (statusword
    0x0637). The next home() starts right after the emulator answered a poll's statusword
    read, so that poll's other reads (position, velocity, ...) wait behind the homing
    start's frames and its status is decoded after the start; the drive answers the mode
    write 130 ms late. The homing (method 17, to the negative limit switch, about half a
    second) completes and the drive reports attained: home() returns and the axis is
    homed. (That older "interrupted" status cleared the homing record, and home() timed
    out, 6 s here, while the drive showed attained.)"""
    drive = SlowModeKinco()
    with anyio.fail_after(40):
        async with served(drive, K_READ_ONLY) as line:
            cfg = machine(line, without_the_homed_bit(tmp_path))
            cfg["axes"]["a"]["homing"]["timeout"] = 6.0
            async with open_machine(cfg) as m:
                a = m.axes["a"]
                await a.enable()

                async def stopped_homing() -> None:
                    with pytest.raises(MotionAborted):
                        await a.home()

                async with anyio.create_task_group() as tg:
                    tg.start_soon(stopped_homing)
                    with anyio.fail_after(5):
                        while drive.motion != "homing":  # noqa: ASYNC110 - the emulator's side
                            await anyio.sleep(0.005)
                    await a.stop()
                assert drive.mode == 6 and drive.statusword() & 0x3400 == 0x0400
                drive.answered = anyio.Event()
                with anyio.fail_after(5):
                    await drive.answered.wait()  # a poll has just read the statusword
                try:
                    await a.home()
                except MotionTimeout:
                    assert drive.homing_done, "the emulator did not complete its homing"
                    raise
                assert drive.homing_done and drive.statusword() & 0x1400 == 0x1400
                assert a.homed and (await a.refresh()).homed
