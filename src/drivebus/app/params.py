"""Parameter backup, compare and restore: what ``drivebus params`` and the service's
``/api/axes/{name}/parameters`` do, on any drive profile.

A drive's documented readable parameters are its profile's data
(``DriveProfile.parameters()``). ``read_parameters`` only reads (a viewing operation: no
write reaches the drive); ``load_parameters`` writes only what differs, in the manual's
order, after every value of the set was checked against its register's range; with
``save`` the drive stores them once at the end (never a save per parameter). A load that
stops part-way raises ``PartialWrite`` naming what the drive took.

A parameter file is TOML: a ``[drive]`` table (family, machine file, axis, address, when)
and a ``[parameters]`` table with one inline table per parameter (``value``, ``unit``,
``register``, ``stored``); a bare number is taken as the value too.
"""

from __future__ import annotations

import contextlib
import time
import tomllib
from collections.abc import AsyncIterator, Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import anyio

from drivebus import text
from drivebus.bus import Bus, Priority
from drivebus.bus.sent import sent_requests
from drivebus.config import MachineConfig, machine_config_in_thread
from drivebus.drives.base import DriveProfile, Parameter
from drivebus.drives.registry import family
from drivebus.errors import (
    ConfigError,
    DrivebusError,
    LimitViolation,
    NotSupported,
    PartialWrite,
)
from drivebus.motion.lines import open_line

__all__ = [
    "Difference",
    "LoadReport",
    "ParameterSet",
    "check_values",
    "diff_parameters",
    "load_parameters",
    "open_drive",
    "plan_load",
    "read_parameters",
]


@dataclass
class ParameterSet:
    """Parameter values of one drive (read from it, or from a file), by key, with where
    they came from."""

    family: str
    values: dict[str, int]
    about: dict[str, Any] = field(default_factory=dict)
    """Where from: machine, axis, address, line, read_at (as a file's ``[drive]`` table)."""
    description: str = ""
    """The description file of a family given as a file (``drive = "drives/x.toml"``),
    which its name alone does not find; "" for a family known by name."""

    @property
    def params(self) -> dict[str, Parameter]:
        """The family's parameters by key."""
        return {p.key: p for p in family(self.description or self.family).profile.parameters()}

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready data: each parameter with its value, unit, register and storage."""
        params = self.params
        return {
            "family": self.family,
            **({"description": self.description} if self.description else {}),
            **{k: v for k, v in self.about.items() if k != "family"},
            "parameters": {k: _parameter_dict(params[k], v) for k, v in self.values.items()},
        }

    def to_toml(self) -> str:
        """The set as a parameter file."""
        params = self.params
        head = [f"# drivebus parameters of {text.a(self.family)} drive"]
        if "axis" in self.about:
            head[0] += f": axis {self.about['axis']}"
        head.append("# restore: drivebus params load FILE [AXIS] [--save]; compare: "
                    "drivebus params diff FILE")
        out = [*head, "", "[drive]", f"family = {_toml(self.family)}"]
        if self.description:
            out.append(f"description = {_toml(self.description)}")
        out += [f"{k} = {_toml(v)}" for k, v in self.about.items() if k != "family"]
        out += ["", "[parameters]"]
        for k, v in self.values.items():
            p = params[k]
            fields = [f"value = {v}"]
            if p.value_unit:
                fields.append(f"unit = {_toml(p.value_unit)}")
            fields += [f"register = {_toml(p.location)}", f"stored = {_toml(p.stored)}"]
            if p.comms:
                fields.append("comms = true")
            out.append(f"{k} = {{ {', '.join(fields)} }}  # {_comment(p, v)}")
        return "\n".join(out) + "\n"

    @classmethod
    def from_toml(cls, text: str, where: str = "parameter file") -> ParameterSet:
        """A parameter file's content; ``ConfigError`` naming the file and the problem."""
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{where}: not TOML: {exc}") from None
        return cls.from_toml_data(data, where)

    @classmethod
    def from_toml_data(cls, data: Mapping[str, Any], where: str) -> ParameterSet:
        """A parameter file's data (as parsed); ``ConfigError`` naming ``where``."""
        drive = data.get("drive")
        if not isinstance(drive, dict) or not isinstance(drive.get("family"), str):
            raise ConfigError(f"{where}: no [drive] table with the drive's family")
        described = drive.get("description", "")
        if not isinstance(described, str):
            raise ConfigError(f"{where}: drive.description: the description file's path, "
                              f"not {described!r}")
        fam = family(described or drive["family"])
        if fam.name.upper() != drive["family"].upper():
            raise ConfigError(f"{where}: {described} describes the {fam.name} drive, not "
                              f"{drive['family']}")
        params = {p.key: p for p in fam.profile.parameters()}
        raw = data.get("parameters")
        if not isinstance(raw, dict):
            raise ConfigError(f"{where}: no [parameters] table")
        unknown = [k for k in raw if k not in params]
        if unknown:
            raise ConfigError(f"{where}: the {fam.name} drive has no parameter "
                              f"{', '.join(unknown)} (it has {', '.join(params)})")
        values: dict[str, int] = {}
        for key in params:  # the manual's order, whatever the file's
            if key not in raw:
                continue
            item = raw[key]
            v = item.get("value") if isinstance(item, dict) else item
            if not isinstance(v, int) or isinstance(v, bool):
                raise ConfigError(f"{where}: parameters.{key}: the value must be a whole "
                                  f"number, not {v!r}")
            values[key] = v
        return cls(fam.name, values, {k: v for k, v in drive.items()
                                      if k not in ("family", "description")},
                   fam.profile.description_file)

    @classmethod
    def from_mapping(cls, family_name: str, values: Mapping[str, object],
                     description: str = "") -> ParameterSet:
        """Values by key for a drive of ``family_name`` (a request body's; ``description``:
        its description file, where the family is one given as a file); ``ConfigError``
        naming unknown keys and values that are no whole numbers."""
        drive = {"family": family_name, **({"description": description} if description
                                           else {})}
        return cls.from_toml_data({"drive": drive, "parameters": dict(values)}, "parameters")

    @classmethod
    def load(cls, path: str | Path) -> ParameterSet:
        """Read a parameter file."""
        p = Path(path)
        try:
            text = p.read_text()
        except OSError as exc:
            raise ConfigError(f"parameter file {p}: {exc.strerror or exc}") from None
        return cls.from_toml(text, str(p))


def _parameter_dict(p: Parameter, value: int) -> dict[str, Any]:
    """One parameter of a set as JSON-ready data: its value and what it takes."""
    out: dict[str, Any] = {
        "value": value, "name": p.name, "unit": p.unit, "register": p.location,
        "stored": p.stored, "comms": p.comms, "range": [p.register.lo, p.register.hi],
        "in_range": p.in_range(value)}
    if p.table:
        out["table"] = list(p.table)
    if meaning := p.meaning(value):
        out["meaning"] = meaning
    return out


def _comment(p: Parameter, value: int) -> str:
    """A parameter line's comment: its name, what the value means, what it takes."""
    meaning = p.meaning(value)
    now = f": {value} = {meaning}" if meaning else ""
    outside = "" if p.in_range(value) else " (OUTSIDE its range: a load refuses it)"
    return f"{p.name}{now}; allowed {p.allowed()}{outside}"


def _toml(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    s = str(v).replace("\\", "\\\\").replace('"', '\\"')
    return f'"{s}"'


async def read_parameters(
    profile: DriveProfile, *, priority: Priority = Priority.POLL,
    about: Mapping[str, Any] | None = None,
) -> ParameterSet:
    """Every documented readable parameter of the drive behind ``profile`` (reads only).
    A viewing operation: by default in turn with the axes' status polls, never ahead of
    them (several clients reading parameters at a higher priority starved the polls, and
    a stop waited 30 s for the status that tells it the drive is at rest)."""
    params = profile.parameters()
    if not params:
        raise NotSupported(f"the {profile.family} profile documents no parameters")
    values = await profile.read_parameter_values(params, priority=priority)
    return ParameterSet(profile.family, {p.key: v for p, v in zip(params, values, strict=True)},
                        dict(about or {}), profile.description_file)


@dataclass(frozen=True)
class Difference:
    """One parameter that differs between two sets (None: absent from that set), with
    the sides whose value is outside the parameter's range."""

    key: str
    name: str
    unit: str
    a: int | None
    b: int | None
    parameter: Parameter | None = None
    outside: tuple[str, ...] = ()
    """"a", "b": the sides holding a value the parameter does not take."""

    def shown(self, value: int | None) -> str:
        """A side's value as a person reads it: "(absent)", "8 (1000 pulses/rev)"."""
        if value is None:
            return "(absent)"
        meaning = self.parameter.meaning(value) if self.parameter is not None else ""
        return f"{value} ({meaning})" if meaning else str(value)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready data."""
        p = self.parameter
        return {"key": self.key, "name": self.name, "unit": self.unit, "a": self.a,
                "b": self.b, "outside_range": list(self.outside),
                **({"range": [p.register.lo, p.register.hi], "allowed": p.allowed()}
                   if p is not None else {})}


def diff_parameters(a: ParameterSet, b: ParameterSet) -> list[Difference]:
    """What differs between ``a`` and ``b`` (same family), in the manual's order; a value
    outside its parameter's range is flagged (``Difference.outside``)."""
    if a.family != b.family:
        raise ConfigError(f"cannot compare {text.a(a.family)} drive's parameters with "
                          f"{text.a(b.family)} drive's")
    out = []
    for key, p in a.params.items():
        va, vb = a.values.get(key), b.values.get(key)
        if va != vb:
            outside = tuple(side for side, v in (("a", va), ("b", vb))
                            if v is not None and not p.in_range(v))
            out.append(Difference(key, p.name, p.value_unit, va, vb, p, outside))
    return out


@dataclass
class Write:
    """One write of a load: the parameter, what the drive holds and what it gets."""

    parameter: Parameter
    old: int | None
    new: int

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready data."""
        return {"key": self.parameter.key, "name": self.parameter.name,
                "unit": self.parameter.unit, "old": self.old, "new": self.new}


@dataclass
class LoadReport:
    """A load's plan and how far it got: the writes, what was written, the save."""

    family: str
    writes: list[Write]
    skipped: list[str] = field(default_factory=list)
    """Parameters that differ but were not written (comms ones, without ``include_comms``)."""
    written: list[str] = field(default_factory=list)
    saved: bool = False
    dry_run: bool = False
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready data."""
        return {"family": self.family, "dry_run": self.dry_run,
                "writes": [w.as_dict() for w in self.writes], "written": self.written,
                "skipped": self.skipped, "saved": self.saved, "notes": self.notes}


def check_values(profile: DriveProfile | type[DriveProfile], wanted: ParameterSet) -> None:
    """``wanted`` is for this drive and every value is in its range (``ConfigError``,
    ``LimitViolation`` naming each one out of range): decided from the file alone, before
    the drive is read or written."""
    if wanted.family != profile.family:
        raise ConfigError(f"the parameters are {text.a(wanted.family)} drive's; this drive "
                          f"is {text.a(profile.family)}")
    problems = []
    for p in profile.parameters():  # the manual's order
        if p.key not in wanted.values:
            continue
        try:
            p.register.check(wanted.values[p.key])
        except LimitViolation as exc:
            problems.append(f"{p.key}: {exc}")
    if problems:
        raise LimitViolation("nothing written: " + "; ".join(problems))


def plan_load(
    profile: DriveProfile | type[DriveProfile], current: ParameterSet, wanted: ParameterSet,
    *, include_comms: bool = False,
) -> LoadReport:
    """The writes that make the drive (holding ``current``) hold ``wanted``: every wanted
    value range-checked (``check_values``), read-only parameters that differ refused,
    comms ones skipped unless ``include_comms``."""
    check_values(profile, wanted)
    params = {p.key: p for p in profile.parameters()}
    problems = []
    report = LoadReport(profile.family, [])
    for key, p in params.items():  # the manual's order
        if key not in wanted.values or wanted.values[key] == current.values.get(key):
            continue
        if not p.writable:
            problems.append(f"{key}: read-only (the drive holds {current.values.get(key)})")
        elif p.comms and not include_comms:
            report.skipped.append(key)
        else:
            report.writes.append(Write(p, current.values.get(key), wanted.values[key]))
    if problems:
        raise ConfigError("nothing written: " + "; ".join(problems))
    return report


async def load_parameters(
    profile: DriveProfile, wanted: ParameterSet, *, save: bool = False, dry_run: bool = False,
    include_comms: bool = False, report: LoadReport | None = None,
    on_write: Callable[[Write], None] | None = None,
) -> LoadReport:
    """Make the drive hold ``wanted``: read it, write only what differs (in the manual's
    order, all values checked first), and with ``save`` store them once at the end.

    A drive with an EEPROM write-through switch has it off for the writes (so no write
    wears the EEPROM) and set back afterwards; a drive without a save command (the BHSS)
    stores the values as they are written instead, with write-through on. ``report``
    (if given) is filled as the load goes, so a caller that is cancelled can say what
    was written; a failed write raises ``PartialWrite`` naming what was written before.
    """
    if save and not profile.saves_by_write_through and (why := profile.save_problem()):
        raise NotSupported(f"--save: {why}")
    check_values(profile, wanted)  # a bad file: refused before the drive is read
    current = await read_parameters(profile, priority=Priority.CONFIG)
    plan = plan_load(profile, current, wanted, include_comms=include_comms)
    if report is None:
        report = plan
    else:
        report.family, report.writes, report.skipped = plan.family, plan.writes, plan.skipped
    report.dry_run = dry_run
    if dry_run or (not report.writes and not save):
        return report
    wt = profile.write_through
    mode: int | None = None
    if wt is not None:
        mode = wt.on if save and profile.saves_by_write_through else wt.off
        was = await profile.read(wt.register)
        if was != mode and report.writes:
            await profile.write(wt.register, mode)
            report.notes.append(f"{wt.register.name} set to {mode} for the load, then back "
                                f"to {was}")
        else:
            mode = None
    try:
        for w in report.writes:
            try:
                with sent_requests() as sent:
                    await profile.write_parameter_value(w.parameter, w.new)
            except DrivebusError as exc:
                keys = [x.parameter.key for x in report.writes]
                left = keys[keys.index(w.parameter.key) + 1 :]
                done = ", ".join(report.written) or "nothing"
                raise PartialWrite(
                    f"the load stopped at {w.parameter.key}: {exc}; written before it: "
                    f"{done}; {w.parameter.key} itself may or may not have been taken "
                    f"(`drivebus params diff` shows it); not written: "
                    f"{', '.join(left) or 'nothing'}; nothing was saved",
                    written=list(report.written),
                ) from exc
            except BaseException:
                # Cancelled: a write that had already left is counted, with what is known
                # of its outcome (the bus waited for it), so the caller can say so.
                if any(r.cancelled for r in sent):
                    outcome = "; ".join(r.outcome for r in sent if r.cancelled)
                    report.written.append(f"{w.parameter.key} (sent as the load was "
                                          f"interrupted: {outcome})")
                raise
            report.written.append(w.parameter.key)
            if on_write is not None:
                on_write(w)
        if save and profile.saves_by_write_through:
            report.saved = True  # each value was stored as it was written
        elif save:
            await profile.save_parameters()
            report.saved = True
    finally:
        if wt is not None and mode is not None:
            with anyio.CancelScope(shield=True):
                try:
                    await profile.write(wt.register, was)
                except DrivebusError as exc:
                    report.notes.append(f"{wt.register.name} could not be set back to {was}: "
                                        f"{exc}")
    return report


@contextlib.asynccontextmanager
async def open_drive(
    config: str | Path | MachineConfig, axis: str, *, timeout: float | None = None
) -> AsyncIterator[DriveProfile]:
    """The profile of ``axis``'s drive on its own line, for the block: only that line is
    opened (a ``sim://`` line reaches a running ``drivebus sim`` or starts its simulator),
    and nothing is written to the drive (no set-up, no axis actor)."""
    cfg = await machine_config_in_thread(config)  # parsing descriptions: off the loop
    ax = cfg.axes.get(axis)
    if ax is None:
        raise ConfigError(f"no axis {axis!r} in machine {cfg.name} (axes: "
                          f"{', '.join(cfg.axes)})")
    line_cfg = cfg.lines[ax.line]
    one = cfg.model_copy(update={"axes": {axis: ax}, "lines": {ax.line: line_cfg}})
    async with contextlib.AsyncExitStack() as stack:
        line, _ = await open_line(one, ax.line, stack)
        bus = await stack.enter_async_context(
            Bus(line, timeout=timeout or line_cfg.timeout, retries=line_cfg.retries))
        slave = bus.slave(ax.address, settings=ax.settings)
        try:
            profile = family(ax.drive).profile(slave, pulses_per_rev=ax.pulses_per_rev,
                                               **ax.drive_options)
        except TypeError as exc:
            raise ConfigError(f"axes.{axis}.drive_options: {exc}") from None
        yield profile


def about_axis(config: MachineConfig, axis: str, source: str | None = None) -> dict[str, Any]:
    """A parameter file's ``[drive]`` entries for ``axis`` of ``config`` (read now)."""
    ax = config.axes[axis]
    about: dict[str, Any] = {}
    if source is not None:
        about["machine"] = source
    about.update(axis=axis, line=ax.line, address=ax.address,
                 read_at=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    return about
