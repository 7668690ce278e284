"""The machine files that ship inside the package, found wherever drivebus is installed.

``DEMO`` is the demo machine: every seed drive kind on the built-in simulator (four drives
at four line settings on one RS-485 line, one on Modbus TCP). ``drivebus demo`` and the
bench's motion scenario run it; ``drivebus demo --write FILE`` copies it out as a start
for a machine file of one's own. A source checkout reaches it as ``configs/demo.toml``
too (a link to this file, not a copy).
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["DEMO"]

DEMO: Path = Path(__file__).resolve().with_name("demo.toml")
"""The demo machine file (``sim://`` lines only)."""
