"""Which simulated twin plays each drive family (the simulator's own registry).

A described family (``drivebus.drives.registry``: a description file) is played by the
generic twin built from the same description (``drivebus.sim.described``); the family whose
profile is still code (the OD2000) has a twin of its own here.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping

from drivebus.drives.registry import FAMILIES, family
from drivebus.errors import ConfigError
from drivebus.sim.described import twin_of
from drivebus.sim.drive import SimDrive
from drivebus.sim.drives.od_drive import SimODDrive

__all__ = ["TWINS", "coded_twin", "twin_class", "twin_of"]

_CODED: dict[str, type[SimDrive]] = {
    "OD2000": SimODDrive,
}
"""The twins written as code, by the family's registry name."""


def _named(name: str) -> type[SimDrive] | None:
    """The generic twins given a class of their own (``drive_id``: what register 93
    reads), imported with their descriptions only when their family is asked for."""
    if name not in ("NT86", "EPR60"):
        return None
    from drivebus.sim.drives.nt_family import SimEPR60, SimNT86

    return SimNT86 if name == "NT86" else SimEPR60


class _Twins(Mapping[str, type[SimDrive]]):
    """The twin class of each built-in family, by the family's registry name; a twin is
    made (its description parsed) when its family is first asked for."""

    def __getitem__(self, name: str) -> type[SimDrive]:
        if name not in FAMILIES:
            raise KeyError(name)
        twin = _CODED.get(name) or _named(name)
        if twin is not None:
            return twin
        spec = FAMILIES[name].spec
        if spec is None:
            raise KeyError(name)
        return twin_of(spec)

    def __iter__(self) -> Iterator[str]:
        return iter([n for n in FAMILIES if n in _CODED or FAMILIES.is_described(n)])

    def __len__(self) -> int:
        return len(list(iter(self)))


TWINS: Mapping[str, type[SimDrive]] = _Twins()
"""The twin class of each built-in family, by the family's registry name (a twin written
as code plays its family even where the profile runs a description)."""


def coded_twin(family_name: str) -> type[SimDrive] | None:
    """The twin written as code of built-in family ``family_name`` (the OD2000's, whose
    frames are not Modbus frames), or None: its description's generic twin plays it."""
    return _CODED.get(family_name.upper())


def twin_class(drive: str) -> type[SimDrive]:
    """The twin of drive ``drive`` (a family name or a description file's reference);
    ``ConfigError`` if the simulator has none."""
    twin = TWINS.get(drive.upper()) if isinstance(drive, str) else None
    if twin is not None:
        return twin
    try:
        fam = family(drive)
    except ConfigError as exc:
        raise ConfigError(f"the simulator has no twin of drive {drive!r}: {exc}") from None
    if fam.spec is None:
        raise ConfigError(f"the simulator has no twin of drive {drive!r} (it has "
                          f"{', '.join(TWINS)} and every described drive)")
    return twin_of(fam.spec)
