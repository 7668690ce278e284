"""Each drive profile identifies its own family, and only it, on the simulated twins; the
scan asks the registry and knows no vendor."""

from __future__ import annotations

import pytest

from drivebus import LineSettings
from drivebus.app.scan import probe
from drivebus.drives.registry import FAMILIES
from drivebus.sim import sim_bus
from drivebus.sim.twins import TWINS

S9600 = LineSettings.parse("9600 8N1")


@pytest.mark.parametrize("name", [n for n in FAMILIES if n != "EPR60"])
async def test_a_family_identifies_its_twin_and_no_other_family_claims_it(name: str) -> None:
    twin = TWINS[name](1, S9600)
    async with sim_bus([twin], S9600, timeout=0.05, retries=0) as (_, bus):
        slave = bus.slave(1)
        claims = {}
        for other, fam in FAMILIES.items():
            if fam.profile.standard_frames == FAMILIES[name].profile.standard_frames:
                claims[other] = await fam.profile.identify(bus.slave(1))
        assert claims[name] is not None and claims[name].family == name
        assert [n for n, ident in claims.items() if ident is not None] == [name]
        found = await probe(bus, 1, S9600)
        assert found is not None and found.family == name, found
        assert slave.address == 1


async def test_the_epr60_is_told_from_the_nt86_by_its_drive_id() -> None:
    twin = TWINS["EPR60"](1, S9600)
    async with sim_bus([twin], S9600, timeout=0.05, retries=0) as (_, bus):
        assert await FAMILIES["NT86"].profile.identify(bus.slave(1)) is None
        ident = await FAMILIES["EPR60"].profile.identify(bus.slave(1))
        assert ident is not None and ident.raw["drive_id"] == 60
