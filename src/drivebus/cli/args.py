"""The command line before the commands see it: global options anywhere, clear usage errors.

``drivebus read PORT 1 0 --trace`` works like ``drivebus --trace read PORT 1 0``: the global
options (``--trace``, ``-v``/``--verbose``, ``--log-level LEVEL``) are moved in front of the
command. An option the command does not have is a usage error naming it and the closest
ones it has (``--setings``: did you mean ``--settings``?), also for the commands that take
negative numbers as arguments (whose parser would otherwise take it for an argument).
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Any

import typer

try:  # typer vendors click from 0.2x on; before, it used click itself
    from typer._click.core import Context
    from typer._click.exceptions import UsageError
except ImportError:  # pragma: no cover
    from click import Context  # type: ignore[assignment]
    from click.exceptions import UsageError  # type: ignore[assignment]

__all__ = [
    "CommandLine",
    "LocalOpt",
    "ServerOpt",
    "TokenOpt",
    "hoist_global_options",
    "parse_command_line",
]

ServerOpt = Annotated[str | None, typer.Option(
    "--server", metavar="URL", envvar="DRIVEBUS_SERVER",
    help="talk to this drivebus serve (default: the one serving CONFIG, if it runs)")]
"""The option of every command that may go through a running ``drivebus serve``."""
TokenOpt = Annotated[str | None, typer.Option(
    "--token", metavar="TOKEN", envvar="DRIVEBUS_TOKEN",
    help="bearer token for --server (from its token file)")]
LocalOpt = Annotated[bool, typer.Option(
    "--local", help="open the machine here even if a drivebus serve owns it")]

_FLAGS = frozenset({"--trace", "--verbose"})
_WITH_VALUE = frozenset({"--log-level"})


def _is_number(token: str) -> bool:
    """A negative number (``-20``, ``-inf``: an argument of ``jog`` or ``move``, checked by
    the command), not an option."""
    try:
        float(token)
    except ValueError:
        return False
    return True


def _is_global(token: str) -> bool:
    return (token in _FLAGS or re.fullmatch(r"-v+", token) is not None
            or token.split("=", 1)[0] in _WITH_VALUE)


def hoist_global_options(args: Sequence[str]) -> list[str]:
    """``args`` (without the program name) with the global options that follow the command
    moved before it, in their order; nothing after ``--`` is touched."""
    front: list[str] = []
    rest: list[str] = []
    seen_command = False
    i = 0
    while i < len(args):
        tok = args[i]
        if tok == "--":
            rest.extend(args[i:])
            break
        if seen_command and _is_global(tok):
            front.append(tok)
            if tok in _WITH_VALUE and i + 1 < len(args):
                front.append(args[i + 1])
                i += 1
        else:
            if not tok.startswith("-") and not seen_command:
                prev = (front + rest)[-1:] or [""]
                seen_command = prev[0] not in _WITH_VALUE
            rest.append(tok)
        i += 1
    return front + rest


@dataclass
class CommandLine:
    """What the command line asks for: the command (None: none given) and its path."""

    command: Any
    path: list[str]
    json: bool
    """The command's ``--json``/``-j`` flag is given."""


def parse_command_line(group: Any, args: Sequence[str]) -> CommandLine:
    """Find the (click) command ``args`` name in ``group`` (sub-commands of ``params``
    included) and check its options; ``UsageError`` naming an option it does not have and
    the closest ones it has."""
    cmd = group
    path = ["drivebus"]
    i = 0
    while hasattr(cmd, "commands"):
        while i < len(args) and args[i].startswith("-"):
            i += 2 if args[i] in _WITH_VALUE else 1  # options of the group itself
        if i >= len(args):
            return CommandLine(None, path, False)
        sub = cmd.commands.get(args[i])
        if sub is None:
            return CommandLine(None, path, False)  # click says "no such command"
        cmd, i = sub, i + 1
        path.append(cmd.name or "")
    known: dict[str, Any] = {"--help": None}
    for p in cmd.params:
        for opt in (*getattr(p, "opts", ()), *getattr(p, "secondary_opts", ())):
            if opt.startswith("-"):
                known[opt] = p
    as_json = False
    skip = False
    for tok in args[i:]:
        if tok == "--":
            break
        if skip:
            skip = False
            continue
        if not tok.startswith("-") or tok == "-" or _is_number(tok):
            continue
        name = tok.split("=", 1)[0] if tok.startswith("--") else tok[:2]
        if name not in known:
            close = difflib.get_close_matches(name, list(known), n=3, cutoff=0.6)
            hint = f"; did you mean {' or '.join(close)}?" if close else ""
            ctx = Context(cmd, info_name=" ".join(path))
            raise UsageError(f"no such option {name}{hint}", ctx=ctx)
        param = known[name]
        if param is None:
            continue
        if name in ("--json", "-j") and getattr(param, "is_flag", False):
            as_json = True
        if getattr(param, "param_type_name", "") == "option" and not param.is_flag and (
                not param.count) and (
                "=" not in tok and (tok.startswith("--") or len(tok) == 2)):
            skip = True  # its value follows
    return CommandLine(cmd, path, as_json)
