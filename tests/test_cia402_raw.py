"""``DriveStatus.raw`` of the CiA 402 engine keeps every polled register's own value, as
the reference promises for any description ("default: every polled register, its own
value: the words before scale and unit"). Before: the engine's raw held only the
statusword, state, mode, error code and inputs, so a position or a velocity in the drive's
own units (the Kinco's DEC) could not be read from it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import anyio
import pytest

from drivebus import open_machine
from waits import until

DRIVES = Path(__file__).resolve().parents[1] / "configs" / "drives"


def machine() -> dict[str, Any]:
    return {"name": "cia402-raw",
            "lines": {"l": {"port": "sim://cia402-raw", "settings": "115200 8N1",
                            "timeout": 0.1}},
            "axes": {"a": {"line": "l", "address": 1, "drive": str(DRIVES / "kinco_fd.toml"),
                           "pulses_per_rev": 10000, "units_per_rev": 10.0, "speed": 20.0,
                           "accel": 200.0, "decel": 200.0,
                           "poll": {"moving": 0.01, "idle": 0.05}}}}


async def test_raw_keeps_each_polled_register_before_scale_and_unit() -> None:
    with anyio.fail_after(30):
        async with open_machine(machine()) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            await a.enable()
            await a.move_to(2.5)  # 2500 pulses
            st = await a.refresh()
            assert st.raw["pos_actual"] == twin.position() == 2500
            assert "statusword" in st.raw and "mode" in st.raw  # the engine's own keys stay
            await a.jog(3.0, watchdog=None)  # 0.3 rev/s = 3000 pulses/s
            await until(lambda: twin.speed_rpm() == pytest.approx(18.0),
                        "the jog to reach its speed on the twin")
            st = await a.refresh()
            # Real_Speed in DEC: pulses/s * 2048/125 (the description's scale 125/2048)
            assert st.raw["real_speed"] == pytest.approx(3000 * 2048 / 125, abs=2)
            assert st.velocity_rpm == pytest.approx(18.0)
            await a.stop()
