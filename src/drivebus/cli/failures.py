"""How the command line reports a failure: one line per distinct cause (``--json``: a JSON
object too) and the gravest cause's exit status (2 usage, 1 runtime, 130 interrupted)."""

from __future__ import annotations

import json
import sys
import termios
from typing import NoReturn

import typer

from drivebus.errors import DrivebusError, leaf_errors

try:  # typer vendors click from 0.2x on; before, it used click itself
    from typer._click.exceptions import UsageError
except ImportError:  # pragma: no cover
    from click.exceptions import UsageError  # type: ignore[no-redef]

__all__ = ["fail", "json_error", "usage"]


def _interrupted(exc: BaseException) -> bool:
    """``exc`` is Ctrl-C, or an error raised because of it (a library that wraps what
    interrupted it, as pydantic does a model being built when Ctrl-C came)."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, KeyboardInterrupt):
            return True
        seen = seen.__cause__ or seen.__context__
    return False


def _explain_any(exc: BaseException) -> tuple[str, int]:
    """``explain`` for the errors drivebus raises on purpose; one line for anything else."""
    if _interrupted(exc):
        return "interrupted", 130
    if isinstance(exc, DrivebusError | OSError | termios.error):
        from drivebus.cli.terminal import explain

        return explain(exc)
    return (f"internal error: {type(exc).__name__}: {exc} (run the command again with --debug "
            f"to see where, and please report it)"), 1


def fail(exc: BaseException, debug: bool) -> NoReturn:
    """Print one line per distinct cause inside ``exc`` and exit with the gravest status
    (``--debug``: the traceback instead)."""
    if debug:
        raise exc
    explained = [_explain_any(e) for e in leaf_errors(exc)]
    for text in dict.fromkeys(t for t, _ in explained):
        typer.echo(text, err=True)
    sys.exit(max(c for _, c in explained))


def usage(exc: UsageError) -> NoReturn:
    """A command-line usage error as one line (exit status 2); no arguments: the help."""
    if type(exc).__name__ == "NoArgsIsHelpError":  # no arguments at all: show the help
        exc.show()
        sys.exit(exc.exit_code)
    where = exc.ctx.command_path if exc.ctx is not None else "drivebus"
    typer.echo(f"error: {exc.format_message().rstrip('.')}; see `{where} --help`", err=True)
    sys.exit(2)


def json_error(exc: BaseException) -> None:
    """With ``--json``, a failure is a JSON object on stdout too (unless the command
    already printed its result there)."""
    from drivebus.cli.terminal import Out

    if Out.results:
        return
    leaves = leaf_errors(exc)
    errors = [{"type": type(e).__name__, "message": _explain_any(e)[0].removeprefix("error: "),
               "exit_status": _explain_any(e)[1]} for e in leaves]
    print(json.dumps({"error": errors[0], **({"errors": errors} if len(errors) > 1 else {})},
                     indent=2), flush=True)
