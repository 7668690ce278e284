"""``python -m drivebus.mqtt CONFIG --mqtt mqtt://HOST:PORT [--node NAME] [--no-discovery]``:
run one plant node: open the machine, bridge it to the broker until SIGINT/SIGTERM, then
say ``offline`` and stop the axes that are moving.

Values on the command line take precedence over the machine file's ``[mqtt]`` section.
Errors are one line on stderr (status 2 for bad arguments or config, 1 otherwise);
``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from drivebus import heap
from drivebus.app import MachineSession
from drivebus.app.lifecycle import run_until_signalled
from drivebus.config import load_config
from drivebus.errors import ConfigError, DrivebusError, leaf_errors
from drivebus.mqtt.bridge import Bridge, BridgeOptions

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m drivebus.mqtt",
        description="Run a drivebus plant node: a machine bridged to an MQTT broker.",
    )
    p.add_argument("config", type=Path, metavar="CONFIG", help="machine file (TOML)")
    p.add_argument("--mqtt", metavar="URL", help="broker, mqtt://HOST[:PORT] "
                   "(default: [mqtt] url of the machine file)")
    p.add_argument("--node", help="node name in the topics (default: [mqtt] node, else the "
                   "machine's name)")
    p.add_argument("--no-discovery", action="store_true",
                   help="publish no Home Assistant discovery")
    p.add_argument("--state-rate", type=float, metavar="HZ",
                   help="most state messages per axis per second (default 10)")
    p.add_argument("--stats-period", type=float, metavar="S",
                   help="seconds between line statistics messages (default 5)")
    p.add_argument("--debug", action="store_true", help="show tracebacks and debug logs")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run a node; the process's exit status."""
    args = _parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.debug else logging.WARNING,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:
        cfg = load_config(args.config)
        options = BridgeOptions.resolve(
            cfg, url=args.mqtt, node=args.node,
            discovery=False if args.no_discovery else None,
            state_rate=args.state_rate, stats_period=args.stats_period,
        )
    except ConfigError as exc:
        if args.debug:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 2

    async def node() -> int:
        async with MachineSession.open(cfg) as session:
            heap.settle()  # (start-up is over: what is alive now stays, see drivebus.heap)
            print(f"node {options.node}: machine {cfg.name} on {options.broker}; "
                  f"Ctrl-C or SIGTERM ends it", flush=True)
            await Bridge(session, options).run()
        return 0

    try:
        return run_until_signalled(node, interrupt_ok=True)
    except (Exception, BaseExceptionGroup) as exc:
        if args.debug:
            raise
        status = 0
        for leaf in dict.fromkeys(leaf_errors(exc)):  # task groups wrap errors in groups
            if isinstance(leaf, DrivebusError | OSError):
                print(f"error: {type(leaf).__name__}: {leaf}", file=sys.stderr)
            else:
                print(f"internal error: {type(leaf).__name__}: {leaf} (--debug shows where)",
                      file=sys.stderr)
            status = max(status, 2 if isinstance(leaf, ConfigError) else 1)
        return status


if __name__ == "__main__":
    sys.exit(main())
