"""``drivebus drive``: check, document and try a drive description before using it.

``check FILE`` validates a description and prints what drivebus understood of it;
``doc FILE`` prints its reference page (the one the docs site shows for the built-in
families); ``try FILE`` runs it against its simulated twin (enable, moves, stop, jog,
home, alarm, power cycle) and prints a pass/fail table. FILE may also be a family's name.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

__all__ = ["drive_app"]

drive_app = typer.Typer(
    name="drive",
    help="Check, document and try a drive description (a TOML file, or a family's name).",
    no_args_is_help=True,
    rich_markup_mode=None,
)

FileArg = Annotated[str, typer.Argument(
    help="a drive description (TOML), or a known family's name", metavar="FILE")]


@drive_app.command("check")
def check(file: FileArg) -> None:
    """Validate a description and print what drivebus understood of it; exit 1 if one of
    the manual's example frames it lists does not come out as the manual prints it."""
    from drivebus.app.drives import check_report, load

    report = check_report(load(file))
    typer.echo(report.text())
    raise typer.Exit(1 if report.failed else 0)


@drive_app.command("doc")
def doc(
    file: FileArg,
    output: Annotated[Path | None, typer.Option(
        "--output", "-o", help="write the page to this file instead of stdout")] = None,
) -> None:
    """Print the description's reference page (markdown)."""
    from drivebus.app.drives import doc_page, load

    page = doc_page(load(file))
    if output is None:
        typer.echo(page, nl=False)
    else:
        output.write_text(page, encoding="utf-8")
        typer.echo(f"written to {output}")


@drive_app.command("try")
def try_(file: FileArg) -> None:
    """Run the description against its simulated twin; exit 1 if a step fails."""
    import anyio

    from drivebus.app.drives import load
    from drivebus.sim.trial import format_trial, try_description

    fam = load(file)
    if fam.spec is None:
        raise typer.BadParameter(f"{fam.name} is a profile written as code, not a description")
    spec = fam.spec
    steps = anyio.run(lambda: try_description(spec))
    typer.echo(format_trial(fam.name, steps))
    raise typer.Exit(1 if any(s.failed for s in steps) else 0)
