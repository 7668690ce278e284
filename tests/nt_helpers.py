"""Shared rig for the NT-family profile tests (NT86, EPR60): a twin on a fast sim bus.

Imported as ``from nt_helpers import ...``: tests/ has no ``__init__.py``, so pytest's
default ("prepend") import mode puts tests/ on ``sys.path`` for its test modules.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any, TypeVar

import anyio

from drivebus import LineSettings
from drivebus.drives.base import DriveProfile, MoveParams
from drivebus.drives.nt_family import NT86Profile
from drivebus.drives.status import DriveStatus
from drivebus.sim import VirtualWire, sim_bus
from drivebus.sim.drives.nt_family import SimNT86

FAST = LineSettings.parse("115200 8N1")
QUICK = MoveParams(speed_rpm=3000, accel_rps2=1000, decel_rps2=1000)

ProfileT = TypeVar("ProfileT", bound=NT86Profile)
SimT = TypeVar("SimT", bound=SimNT86)


@asynccontextmanager
async def nt_rig(
    sim: SimT, profile_cls: type[ProfileT], **opts: Any
) -> AsyncIterator[tuple[VirtualWire, ProfileT, SimT]]:
    """``sim`` on a 115200 8N1 sim bus and a set-up ``profile_cls`` for it (log cleared)."""
    async with sim_bus([sim], FAST) as (wire, bus):
        profile = profile_cls(bus.slave(1), **opts)
        await profile.setup()
        wire.clear_log()
        yield wire, profile, sim


async def wait_for(
    profile: DriveProfile, pred: Callable[[DriveStatus], bool], timeout: float = 5.0
) -> DriveStatus:
    """Poll the drive through the profile until ``pred`` holds (bounded by ``timeout``)."""
    with anyio.fail_after(timeout):
        while True:
            st = await profile.read_status()
            if pred(st):
                return st
            await anyio.sleep(0.005)


def idle(st: DriveStatus) -> bool:
    """At rest: neither moving nor homing."""
    return not st.moving and not st.homing


def sent(wire: VirtualWire) -> list[str]:
    """Request frames on the wire, as the manual writes them."""
    return [f.data.hex(" ").upper() for f in wire.requests()]
