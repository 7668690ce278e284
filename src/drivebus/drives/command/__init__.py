"""The command engine: a ``DriveProfile`` driven by a drive description.

It runs the description's procedures step by step (register and block writes with values
computed from the call, command codes, control-word bits, read-modify-writes, read-backs
and checks, bounded waits, calls of other procedures), polls and decodes the status, and
learns what decoding needs with reads only (``learn``) apart from the writes of ``setup``.
Every procedure is first run dry, without I/O: every value it will write is computed and
range-checked before the first frame, so a bad argument never leaves a command half-sent.

In rooms: ``base`` (its state and the names expressions see), ``runs`` (a procedure's
run), ``reads`` (read plans), ``procedures`` (the runner), ``writes`` (codecs and
writes), ``status`` (reads decoded, the status), ``setup``, ``motion``, ``homing``,
``programs``; ``profile`` puts them together as ``DescribedProfile``.
``drivebus.drives.engine.profile_class(description)`` makes the profile class of a
description (on this engine or the CiA 402 one)."""

from __future__ import annotations

from drivebus.drives.command.profile import DescribedProfile
from drivebus.drives.command.reads import ReadPlan, plan_reads

__all__ = ["DescribedProfile", "ReadPlan", "plan_reads"]
