"""Reading a description: the TOML file (over the one it ``extends``), the manual's
parameter numbers resolved to addresses, the models validated and the cross-checks
run; any mistake is one ``ConfigError`` naming the file, the key path and the problem.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from drivebus.checks import validation_problems
from drivebus.drives.description.checks import Checker
from drivebus.drives.description.link import ParameterNumbers
from drivebus.drives.description.model import Description
from drivebus.drives.expr import ExprError
from drivebus.errors import ConfigError


def parse_description(data: Mapping[str, Any], source: str = "description") -> Description:
    """Validate a description mapping; one ``ConfigError`` names ``source``, each key
    path and the problem."""
    data = _numbered(data, source)
    try:
        desc = Description.model_validate(dict(data))
    except ValidationError as exc:
        problems = "; ".join(validation_problems(exc, model=Description, limit=8))
        raise ConfigError(f"{source}: {problems}") from None
    problems = list(Checker(desc).problems())
    if problems:
        shown = problems[:8] + ([f"and {len(problems) - 8} more"] if len(problems) > 8 else [])
        raise ConfigError(f"{source}: {'; '.join(shown)}")
    return desc


def _numbered(data: Mapping[str, Any], source: str) -> dict[str, Any]:
    """``data`` with each register address given as the manual's parameter number
    (``address = "P5-07"``) replaced by the address ``[link] parameter_numbers`` gives it;
    one ``ConfigError`` naming the register's key otherwise."""
    registers = data.get("registers")
    out = dict(data)
    if not isinstance(registers, dict) or not any(
            isinstance(r, dict) and any(isinstance(r.get(f), str) for f in _NUMBERED)
            for r in registers.values()):
        return out
    link = data.get("link", {})
    rule = link.get("parameter_numbers") if isinstance(link, dict) else None
    try:
        numbers = ParameterNumbers.model_validate(rule) if rule is not None else None
    except ValidationError as exc:
        problems = "; ".join(validation_problems(exc, model=ParameterNumbers,
                                                 prefix="link.parameter_numbers"))
        raise ConfigError(f"{source}: {problems}") from None
    resolved = {}
    for key, reg in registers.items():
        if isinstance(reg, dict):
            reg = dict(reg)
            for f in _NUMBERED:
                number = reg.get(f)
                if not isinstance(number, str):
                    continue
                if numbers is None:
                    raise ConfigError(
                        f"{source}: registers.{key}.{f}: {number!r} is not an address: give "
                        "a number (6, 0x0006) or, where the manual numbers its parameters "
                        "(a parameter number such as 'P5-07'), say how numbers give "
                        "addresses in [link] parameter_numbers = { pattern = "
                        "'P{group}-{number}', address = 'group * 0x100 + number * 2' }")
                try:
                    reg[f] = numbers.resolve(number)
                except (ValueError, ExprError) as exc:
                    raise ConfigError(f"{source}: registers.{key}.{f}: {exc}") from None
                if f == "address":
                    reg.setdefault("name", number)
        resolved[key] = reg
    out["registers"] = resolved
    return out


_NUMBERED = ("address", "low_address")


def read_toml(p: Path, noun: str) -> dict[str, Any]:
    """The TOML file ``p`` (a ``noun``: "drive description", "config file") as a mapping;
    one ``ConfigError`` naming the file when it is missing, unreadable or not TOML."""
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such {noun}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not a text file (not UTF-8 at byte {exc.start})") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the {noun}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None


def _extended(data: dict[str, Any], p: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    """``data`` over the description it ``extends`` (a file relative to ``p``, or a
    packaged description by its family, ``extends = "NT86"``): each
    section's keys replace the base's whole (a register, an option, a procedure,
    ``homing.methods``, a ``[link]`` key), and ``remove = { registers = [...] }`` drops
    entries of the base."""
    ref = data.pop("extends", None)
    remove = data.pop("remove", {})
    if ref is None:
        if remove:
            raise ConfigError(f"{p}: remove: only a description that extends another removes")
        return data
    if not isinstance(ref, str):
        raise ConfigError(f"{p}: extends: expected a file name, got {ref!r}")
    base_path = (p.parent / ref).resolve() if ref.endswith(".toml") else _packaged(p, ref)
    if base_path in seen:
        raise ConfigError(f"{p}: extends: {ref} extends it in turn")
    base = _extended(read_toml(base_path, "drive description"), base_path, (*seen, p.resolve()))
    out = dict(base)
    for section, value in data.items():
        old = out.get(section)
        if not isinstance(value, dict) or not isinstance(old, dict):
            out[section] = value
        else:
            out[section] = {**old, **value}
    if not isinstance(remove, dict):
        raise ConfigError(f"{p}: remove: expected a table of section = [keys]")
    for section, keys in remove.items():
        entries = dict(out.get(section, {}))
        for key in keys if isinstance(keys, list) else [keys]:
            if key not in entries:
                raise ConfigError(f"{p}: remove.{section}: {ref} has no {section}.{key}")
            del entries[key]
        out[section] = entries
    return out


PACKAGED = Path(__file__).resolve().parents[1] / "descriptions"
"""The descriptions drivebus ships (``extends = "NT86"`` names one by its family)."""


def _packaged(p: Path, family: str) -> Path:
    """The packaged description of ``family`` (its file is the family's name, in lower
    case); ``ConfigError`` naming those there are."""
    found = PACKAGED / f"{family.lower()}.toml"
    if not found.is_file():
        there = ", ".join(sorted(f.stem.upper() for f in PACKAGED.glob("*.toml")))
        raise ConfigError(f"{p}: extends: {family!r} is no packaged description ({there}; "
                          f"a file of your own ends in .toml, relative to this one)")
    return found


def load_description(path: str | Path) -> Description:
    """Read and check the description file ``path`` (over the one it ``extends``)."""
    p = Path(path)
    data = _extended(read_toml(p, "drive description"), p)
    return parse_description(data, str(p))
