"""What the ``drivebus`` commands share: their common arguments and options, and finding
the ``drivebus serve`` that owns a machine (used by ``cli`` and its command modules)."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from drivebus.cli.args import LocalOpt, ServerOpt, TokenOpt
from drivebus.errors import ArgumentError

if TYPE_CHECKING:
    from drivebus.service.client import ServiceClient

__all__ = ["ConfigArg", "JsonOpt", "LocalOpt", "ServerOpt", "TokenOpt", "check_output",
           "machine_file", "owner"]

_URL = re.compile(r"([a-z][a-z0-9+.-]+):/+(.*)")
"""A line's URL as a path makes it (``sim://x`` -> ``sim:/x``)."""


def machine_file(ctx: typer.Context, value: Path) -> Path:
    """CONFIG as the command takes it: a line (``sim://NAME``, ``tcp://HOST``, a serial
    device) is not a machine file, and the command says what it takes instead."""
    text = str(value)
    m = _URL.fullmatch(text)
    line = f"{m.group(1)}://{m.group(2)}" if m else text if text.startswith("/dev/") else None
    if line is None:
        return value
    usage = f"{ctx.command_path} MACHINE.toml" + (" AXIS" if ctx.command.name == "dump" else "")
    settings = "" if line.startswith("tcp://") else " -S SETTINGS"
    raise ArgumentError(
        f"CONFIG: {line} is a line, not a machine file: `{ctx.command_path}` takes a machine "
        f"file (TOML){' and an axis' if usage.endswith('AXIS') else ''}: `{usage}`; a slave "
        f"on a line is read with `drivebus read {line} ADDR REG{settings}` (`drivebus scan "
        f"{line}` finds the slaves)")


ConfigArg = Annotated[Path, typer.Argument(help="machine file (TOML)", metavar="CONFIG",
                                           callback=machine_file)]
JsonOpt = Annotated[bool, typer.Option("--json", "-j", help="print the result as JSON")]


def check_output(output: Path, option: str = "--output", example: str = "axis.toml") -> None:
    """``option`` names a file that can be written: its directory exists and takes it
    (``ArgumentError`` naming the path otherwise, before anything is read or moved)."""
    where = output.parent
    if output.is_dir():
        raise ArgumentError(f"{option} {output}: is a directory: give a file's name "
                            f"(e.g. {output / example})")
    if not where.is_dir():
        raise ArgumentError(f"{option} {output}: no such directory {where}: create it "
                            f"first, or write the file elsewhere")
    if not os.access(where, os.W_OK | os.X_OK) or (
            output.exists() and not os.access(output, os.W_OK)):
        raise ArgumentError(f"{option} {output}: not writable by this user (in {where})")


def owner(
    config: Path, server: str | None, token: str | None, local: bool
) -> ServiceClient | None:
    """The ``drivebus serve`` that owns ``config``'s machine (``--server``, or found
    through the file), as a client; None to open the machine here."""
    from drivebus.cli.remote import service_owner

    return service_owner(config, server, token, local)
