"""The ``drivebus`` command line."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import anyio
import typer

from drivebus.errors import DrivebusError

app = typer.Typer(
    name="drivebus",
    help="Modbus stepper and servo drives on shared RS-485 lines and Modbus TCP.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)


@app.command()
def bench(
    quick: Annotated[bool, typer.Option("--quick", help="short runs (under a minute)")] = False,
    turnaround: Annotated[float, typer.Option(help="simulated slave turnaround, s")] = 0.001,
    json_path: Annotated[
        Path | None, typer.Option("--json", help="also write the results as JSON here")
    ] = None,
) -> None:
    """Measure bus efficiency, stop latency, CPU per transaction and scale on simulated lines."""
    from drivebus.bench import format_table, results_json, run_bench

    results = anyio.run(lambda: run_bench(quick=quick, turnaround=turnaround))
    typer.echo(format_table(results))
    if json_path is not None:
        json_path.write_text(results_json(results))
        typer.echo(f"\nresults written to {json_path}")


@app.command()
def demo(
    config: Annotated[
        Path | None, typer.Argument(help="machine file (default: the built-in demo machine)")
    ] = None,
) -> None:
    """Run the demo job on the built-in simulator: home, group moves, a jog, a stop."""
    from drivebus.demo import run_demo

    raise typer.Exit(anyio.run(run_demo, config))


def main() -> None:
    """Console-script entry point: one clear line per error, no traceback."""
    debug = "--debug" in sys.argv
    if debug:
        sys.argv.remove("--debug")
    try:
        app()
    except DrivebusError as exc:
        if debug:
            raise
        typer.echo(f"error: {exc}", err=True)
        sys.exit(2)


__all__ = ["app", "main"]
