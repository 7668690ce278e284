"""The ``drivebus`` command line, one module per concern: ``root`` (the commands and the
entry point), ``args``/``options`` (parsing), ``terminal`` (output, signals, progress),
``views`` (tables of a running machine), ``commissioning``, ``positions``, ``record``,
``drive`` (``drivebus drive check/doc/try``) and ``demo``.

``main`` is the console script's entry point; importing this package imports nothing else,
so a command pays only for what it uses.
"""

from __future__ import annotations


def main() -> None:
    """Console-script entry point (``drivebus``): see ``drivebus.cli.root.main``. Ctrl-C
    while it starts (nothing is open yet) is ``interrupted``, exit status 130."""
    try:
        from drivebus.cli.root import main as run
    except KeyboardInterrupt:
        import sys

        print("interrupted", file=sys.stderr, flush=True)
        sys.exit(130)
    run()


__all__ = ["main"]
