"""Taught positions: named positions of one or more axes, kept with the machine file.

A machine file names its positions in a ``[positions]`` section, one table per name::

    [positions.pick]      # above the tray
    x = 120.0
    y = 40.0

or keeps them in a file beside it (``positions_file = "positions.toml"``, the same
tables), which is then the file teaching writes to. ``PositionStore.teach`` writes a
position back atomically (a temporary file beside it, flushed, then renamed over it),
keeping the file's comments and layout (tomlkit); the file is read back and checked
before the rename, so a failed teach leaves the old file as it was.
"""

from __future__ import annotations

import os
import tempfile
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import tomlkit

from drivebus.config import (
    POSITION_NAME,
    POSITION_NAME_RULE,
    MachineConfig,
    is_position_name,
    position_problems,
)
from drivebus.errors import ArgumentError, ConfigError, NotFound

__all__ = ["POSITION_NAME", "PositionStore", "position_problems"]  # the names: from config

_DIGITS = 6
"""Decimals a taught value keeps (a micrometre in millimetres)."""


@dataclass
class PositionStore:
    """A machine's taught positions and the file they are kept in (None: in memory only,
    a machine opened from a mapping)."""

    config: MachineConfig
    path: Path | None
    positions: dict[str, dict[str, float]] = field(default_factory=dict)

    @classmethod
    def of(cls, config: MachineConfig, source: Path | None) -> PositionStore:
        """The positions of ``config`` (loaded from ``source``, the machine file, if it
        was a file): its own ``[positions]``, or its ``positions_file``'s, checked."""
        if config.positions_file is None:
            return cls(config, source, {n: dict(v) for n, v in config.positions.items()})
        base = source.parent if source is not None else Path.cwd()
        path = base / config.positions_file
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8")) if path.exists() else {}
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            raise ConfigError(f"{path}: cannot read the positions file: {exc}") from None
        positions = data.get("positions", {})
        problems = position_problems(config, positions)
        extra = sorted(set(data) - {"positions"})
        if extra:
            problems.append(f"{', '.join(extra)}: a positions file holds only [positions]")
        if problems:
            raise ConfigError(f"{path}: {'; '.join(problems)}")
        return cls(config, path, {n: {a: float(v) for a, v in t.items()}
                                  for n, t in positions.items()})

    def get(self, name: str) -> dict[str, float]:
        """The position called ``name``; ``NotFound`` naming those there are."""
        try:
            return dict(self.positions[name])
        except KeyError:
            known = ", ".join(self.positions) or "none taught yet"
            raise NotFound(f"no position {name!r} (positions: {known})") from None

    def teach(self, name: str, values: Mapping[str, float]) -> dict[str, float]:
        """Store ``values`` (axis -> position) under ``name`` (the axes it already had
        keep theirs) and write the file back; returns the position as stored."""
        if not is_position_name(name):
            raise ArgumentError(f"position name {name!r}: {POSITION_NAME_RULE}")
        rounded = {a: round(float(v), _DIGITS) for a, v in values.items()}
        merged = {**self.positions.get(name, {}), **rounded}
        problems = position_problems(self.config, {name: merged})
        if problems:
            raise ArgumentError("; ".join(problems))
        if self.path is not None:
            self._write(name, merged)
        self.positions[name] = merged
        return dict(merged)

    def _write(self, name: str, position: dict[str, float]) -> None:
        """Write ``position`` into the file atomically, keeping comments and layout."""
        assert self.path is not None
        path = self.path
        try:
            text = path.read_text(encoding="utf-8") if path.exists() else ""
            doc = tomlkit.parse(text)
        except (OSError, UnicodeDecodeError, tomlkit.exceptions.ParseError) as exc:
            raise ConfigError(f"{path}: cannot read it to teach {name!r}: {exc}") from None
        table = doc.get("positions")
        if table is None:
            table = tomlkit.table(is_super_table=True)
            doc["positions"] = table
        entry = table.get(name)
        if entry is None:
            entry = tomlkit.table()
            table[name] = entry
        for axis, value in position.items():
            entry[axis] = value
        out = tomlkit.dumps(doc)
        check = tomllib.loads(out).get("positions", {}).get(name, {})
        if {a: float(v) for a, v in check.items()} != position:
            raise ConfigError(f"{path}: position {name!r} did not read back as written")
        _replace(path, out)


def _replace(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically: a flushed temporary file renamed over it."""
    mode = path.stat().st_mode & 0o777 if path.exists() else 0o644
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
