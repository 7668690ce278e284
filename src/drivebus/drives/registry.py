"""Which profile belongs to a drive family: the registry of drive families.

A drive family is a description (``drivebus/drives/descriptions/*.toml``, run by an
engine) or, where its frames or behaviour cannot be data, a profile class in
``drivebus.drives``. Descriptions are found, in this order:

* built in: the files shipped inside the package (``FAMILIES`` holds them with the
  hand-written profiles);
* by path: ``drive = "drives/my_servo.toml"`` in a machine file (relative to that file);
* in the directories of the environment variable ``DRIVEBUS_DRIVES_PATH`` (separated
  like ``PATH``) and of ``add_drives_path`` (a machine file's ``drives_path``);
* from other packages: entry points of the group ``drivebus.drives``, each naming a
  module (its package's ``*.toml`` files) or a function returning directories or files.

A family found by path keeps its file's absolute path as its reference
(``AxisConfig.drive``), so that every tool reading the machine file finds it again.
"""

from __future__ import annotations

import atexit
import inspect
import os
import re
import shutil
import sys
import tempfile
import threading
import tomllib
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from importlib import resources
from importlib.metadata import entry_points
from importlib.resources.abc import Traversable
from pathlib import Path
from types import ModuleType
from typing import Any

from drivebus.drives.base import DriveProfile
from drivebus.drives.description import Description, load_description
from drivebus.drives.engine import profile_class
from drivebus.drives.od_drive import ODDriveProfile
from drivebus.errors import ConfigError

__all__ = [
    "ENTRY_POINT_GROUP",
    "ENV_PATH",
    "FAMILIES",
    "BuiltinFamilies",
    "DriveFamily",
    "add_drives_path",
    "all_families",
    "builtin_description",
    "drive_label",
    "family",
    "family_from_description",
    "is_file_reference",
    "resolve_drive",
]

ENV_PATH = "DRIVEBUS_DRIVES_PATH"
ENTRY_POINT_GROUP = "drivebus.drives"


@dataclass(frozen=True)
class DriveFamily:
    """A drive family: its name, its profile and the link it uses."""

    name: str
    profile: type[DriveProfile]
    link: str
    """"rtu" or "tcp"."""
    description: str
    spec: Description | None = None
    """The drive description the profile runs (None: a hand-written profile)."""
    source: str = ""
    """Where the description came from (a file path, or "built in")."""

    @property
    def default_pulses_per_rev(self) -> int:
        """The pulses per revolution an axis takes when its machine file gives none: the
        description's ``[units.pulses_per_rev] default``, else the profile's own."""
        if self.spec is not None:
            return int(self.spec.units.pulses_per_rev.default)
        return int(inspect.signature(self.profile).parameters["pulses_per_rev"].default)


def family_from_description(d: Description, source: str = "") -> DriveFamily:
    """The family of a description: its engine's profile class."""
    return DriveFamily(d.family, profile_class(d), d.link.protocol,
                       d.drive.description or d.drive.model or d.family, d, source)


def _builtin_files() -> Iterator[Any]:
    root = resources.files("drivebus.drives").joinpath("descriptions")
    if not root.is_dir():  # no family is shipped as a description (yet)
        return
    for entry in sorted(root.iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".toml"):
            yield entry


def builtin_description(name: str) -> Description:
    """The built-in description of family ``name``."""
    fam = FAMILIES.get(name.upper())
    if fam is None or fam.spec is None:
        raise ConfigError(f"no built-in description of drive {name!r}")
    return fam.spec


_PROFILES: tuple[DriveFamily, ...] = (
    DriveFamily("OD2000", ODDriveProfile, "rtu",
                "2000h object-dictionary drive (settings and monitoring only)"),
)
"""The families whose profiles are still code (each says why in its module)."""

_ORDER = ("NT86", "EPR60", "BHSS", "CL86R", "OD2000")
"""How the built-in families are listed (the others after them, by name)."""

_PARSING = threading.RLock()
"""Held while a description is parsed (machine files are validated in worker threads)."""

_DECLARED = re.compile(r'^family\s*=\s*"([^"\n]+)"', re.M)


class BuiltinFamilies(Mapping[str, DriveFamily]):
    """The built-in families by name: the hand-written profiles and the shipped
    descriptions. A description is parsed (and its profile class built) when its family
    is first looked up, so that a command pays only for the drives its machine names."""

    def __init__(self) -> None:
        self._loaded: dict[str, DriveFamily] = {}
        self._names: list[str] | None = None
        self._files: dict[str, Any] = {}

    def _index(self) -> list[str]:
        """The families' names, from each shipped file's declared family (read cheaply)."""
        if self._names is None:
            for entry in _builtin_files():
                text = entry.read_text(encoding="utf-8")
                m = _DECLARED.search(text)
                name = m.group(1) if m else _family_name_of(text)
                if name is None:  # not a description: loading it says why
                    name = Path(entry.name).stem
                self._files[name] = entry
            known = {f.name for f in _PROFILES} | set(self._files)
            self._names = [n for n in _ORDER if n in known] + sorted(known - set(_ORDER))
        return self._names

    def __getitem__(self, name: str) -> DriveFamily:
        fam = self._loaded.get(name)
        if fam is not None:
            return fam
        with _PARSING:  # one parse per family, whichever thread asks first
            return self._load(name)

    def _load(self, name: str) -> DriveFamily:
        fam = self._loaded.get(name)
        if fam is not None:
            return fam
        self._index()
        entry = self._files.get(name)
        if entry is None:  # a hand-written profile (a description of the name wins)
            fam = next((f for f in _PROFILES if f.name == name), None)
            if fam is None:
                raise KeyError(name)
            self._loaded[name] = fam
            return fam
        with resources.as_file(entry) as path:
            d = load_description(path)
        if d.family != name:
            raise ConfigError(f"{entry.name}: a built-in description of family {name!r} "
                              f"declares {d.family!r}")
        fam = self._loaded[name] = family_from_description(d, "built in")
        return fam

    def __contains__(self, name: object) -> bool:
        return name in self._index()

    def __iter__(self) -> Iterator[str]:
        return iter(self._index())

    def __len__(self) -> int:
        return len(self._index())

    def is_described(self, name: str) -> bool:
        """True if built-in family ``name`` ships as a description (not parsed here)."""
        self._index()
        return name in self._files

    def loaded(self) -> list[str]:
        """The families looked up (and so parsed) so far."""
        return [n for n in self._index() if n in self._loaded]


FAMILIES: BuiltinFamilies = BuiltinFamilies()
"""The built-in families, by name: the hand-written profiles and the shipped descriptions
(each description parsed on first use)."""


# -- descriptions outside the package -------------------------------------------------------

_extra_paths: list[Path] = []
_file_cache: dict[Path, tuple[float, DriveFamily]] = {}


def add_drives_path(directory: str | os.PathLike[str]) -> None:
    """Look for descriptions (``*.toml``) in ``directory`` too (after the environment's)."""
    p = Path(directory).resolve()
    if p not in _extra_paths:
        _extra_paths.append(p)


def _search_dirs() -> list[Path]:
    env = os.environ.get(ENV_PATH, "")
    dirs = [Path(p).expanduser().resolve() for p in env.split(os.pathsep) if p.strip()]
    return dirs + [p for p in _extra_paths if p not in dirs]


def is_file_reference(ref: str) -> bool:
    """True if ``ref`` names a description file rather than a family."""
    return ref.endswith(".toml") or "/" in ref or os.sep in ref


def _from_file(path: Path) -> DriveFamily:
    p = path.resolve()
    try:
        mtime = p.stat().st_mtime
    except OSError:
        raise ConfigError(f"{path}: no such drive description") from None
    with _PARSING:
        cached = _file_cache.get(p)
        if cached is not None and cached[0] == mtime:
            return cached[1]
        fam = family_from_description(load_description(p), str(p))
        fam.profile.description_file = str(p)  # its own class: the file finds it again
        _file_cache[p] = (mtime, fam)
        return fam


def _family_name(path: Path) -> str | None:
    """The family a description file declares (read cheaply, without checking it)."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    return _family_name_of(text)


def _family_name_of(text: str) -> str | None:
    """The family a description's text declares, if it is TOML with a [drive] family."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        return None
    drive = data.get("drive")
    name = drive.get("family") if isinstance(drive, dict) else None
    return name if isinstance(name, str) else None


def _files_in(directory: Path) -> list[Path]:
    try:
        return sorted(p for p in directory.iterdir() if p.suffix == ".toml" and p.is_file())
    except OSError:
        return []


_plugins: tuple[tuple[str, ...], list[Path]] | None = None
"""The plug-ins' description files, and the ``sys.path`` they were found on."""


def _entry_point_files() -> list[Path]:
    """The description files the installed plug-ins ship, found again only when
    ``sys.path`` has changed: asking ``importlib.metadata`` reads every installed
    distribution's metadata (16 ms on Python 3.11 and 60 ms on 3.13 with 94 of them),
    and a scan asks before every probe, on the event loop. A plug-in installed while the
    process runs is seen after a restart."""
    global _plugins
    where = tuple(sys.path)
    if _plugins is None or _plugins[0] != where:
        _plugins = (where, list(_installed_plugin_files()))
    return _plugins[1]


def _installed_plugin_files() -> Iterator[Path]:
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            target = ep.load()
        except Exception as exc:  # a broken plug-in must not break the other drives
            raise ConfigError(f"entry point {ep.name} ({ep.value}) of group "
                              f"{ENTRY_POINT_GROUP} cannot be loaded: {exc}") from exc
        yield from _plugin_files(target, ep.name)


_copies: Path | None = None
"""Where the files of zipped plug-ins are copied out to (removed at exit)."""


def _copied_out(plugin: str, entry: Traversable) -> Path:
    """A zipped plug-in's description as a file of its own (the list of plug-in files is
    kept, so a temporary copy that ends with a ``with`` block would not do)."""
    global _copies
    if _copies is None:
        _copies = Path(tempfile.mkdtemp(prefix="drivebus-plugins-"))
        atexit.register(shutil.rmtree, _copies, ignore_errors=True)
    path = _copies / plugin / entry.name
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(entry.read_bytes())
    return path


def _plugin_files(target: Any, name: str) -> Iterator[Path]:
    if isinstance(target, ModuleType):
        root = resources.files(target)
        for entry in root.iterdir():
            if entry.name.endswith(".toml"):
                yield entry if isinstance(entry, Path) else _copied_out(name, entry)
        return
    if callable(target):
        target = target()
    items: Iterable[Any] = [target] if isinstance(target, str | os.PathLike) else target
    for item in items:
        p = Path(item)
        if p.is_dir():
            yield from _files_in(p)
        elif p.suffix == ".toml":
            yield p
        else:
            raise ConfigError(f"entry point {name} of group {ENTRY_POINT_GROUP} gave "
                              f"{item!r}: neither a directory nor a .toml file")


def _found_files() -> Iterator[Path]:
    for d in _search_dirs():
        yield from _files_in(d)
    yield from _entry_point_files()


def resolve_drive(ref: str, base: str | os.PathLike[str] | None = None) -> str:
    """The canonical reference of drive ``ref``: a family's name, or the absolute path of
    a description file (``ref`` relative to ``base``); ``ConfigError`` if unknown."""
    if not isinstance(ref, str) or not ref.strip():
        raise ConfigError(f"a drive is a family name or a description file, not {ref!r}")
    if is_file_reference(ref):
        p = Path(ref).expanduser()
        if not p.is_absolute():
            p = Path(base or ".") / p
        return str(_from_file(p).source)
    return ref.upper() if ref.upper() in FAMILIES else _search(ref)[0]


def _search(name: str) -> tuple[str, DriveFamily]:
    for path in _found_files():
        declared = _family_name(path)
        if declared is not None and declared.upper() == name.upper():
            fam = _from_file(path)
            return fam.source, fam
    known = ", ".join(f.name for f in all_families())
    raise ConfigError(f"unknown drive {name!r}: known drives are {known} (or give a "
                      f"description file, drive = \"drives/my_drive.toml\")")


def family(name: str) -> DriveFamily:
    """The family called ``name`` (case-insensitive), or described in file ``name``;
    ``ConfigError`` listing the known ones."""
    if not isinstance(name, str):
        raise ConfigError(f"unknown drive {name!r}: known drives are {', '.join(FAMILIES)}")
    f = FAMILIES.get(name.upper())
    if f is not None:
        return f
    if is_file_reference(name):
        return _from_file(Path(name).expanduser())
    return _search(name)[1]


def drive_label(ref: str) -> str:
    """How to name drive ``ref`` to a person: its family, and the file it is described in
    when it is one outside the package (``MOONS-STF (drives/moons_stf.toml)``)."""
    if not is_file_reference(ref):
        return ref
    try:
        fam = family(ref)
    except ConfigError:
        return ref
    return f"{fam.name} ({os.path.relpath(ref) if os.path.isabs(ref) else ref})"


def all_families() -> list[DriveFamily]:
    """The built-in families, then those found on the search path and in plug-ins (a
    broken file there is skipped here; naming it gives its error)."""
    out = list(FAMILIES.values())
    seen = set(FAMILIES)
    for path in _found_files():
        try:
            fam = _from_file(path)
        except ConfigError:
            continue
        if fam.name.upper() not in seen:
            seen.add(fam.name.upper())
            out.append(fam)
    return out
