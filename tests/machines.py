"""The demo machine as the tests load it: in this process, or with its lines served by
worker processes."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

__all__ = ["DEMO", "STARVED_HOST_TIMEOUT", "Machinefile", "demo_machine"]

DEMO = Path(__file__).resolve().parents[1] / "configs" / "demo.toml"

Machinefile = Path | dict[str, Any]

STARVED_HOST_TIMEOUT = 1.0
"""The response timeout of the demo's lines when a worker process serves them, seconds.
The simulated drives answer from the test's own process, and a worker keeps its own time:
on a loaded two-core host the test's process went 343 ms without the CPU while its
worker timed out a write (0.1 s), retried it, and the retries met the late reply on the
simulated wire (a collision, a bad CRC, the group move failed). A real drive is not
starved with its master, so the demo keeps 0.1 s; in this process drives and master
wait together."""


def demo_machine(workers: int = 0) -> Machinefile:
    """The demo machine, its lines served by ``workers`` worker processes (0: by the
    machine's own process, the demo file as it is)."""
    if not workers:
        return DEMO
    cfg = tomllib.loads(DEMO.read_text())
    cfg["workers"] = workers
    for line in cfg["lines"].values():
        line["timeout"] = STARVED_HOST_TIMEOUT
    return cfg
