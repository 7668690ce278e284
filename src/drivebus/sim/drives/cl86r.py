"""SimCL86R: the CL86R's simulated twin, played from its description.

The twin's choices where the manual is silent are written in the description's ``[twin]``
section (``drivebus/drives/descriptions/cl86r.toml``).
"""

from __future__ import annotations

from drivebus.drives.registry import builtin_description
from drivebus.sim.described import twin_of

__all__ = ["SimCL86R"]

SimCL86R = twin_of(builtin_description("CL86R"))
"""The simulated CL86R (``drivebus.sim.described.DescribedDrive`` on its description)."""
