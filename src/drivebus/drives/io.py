"""Digital I/O by name: the terminals a drive family has, and what each is set to do.

A profile declares its inputs and outputs (``DriveProfile.io_inputs``/``io_outputs``, the
names its manual gives the terminals, in the order of the bits of its I/O status
registers) and reads their states from the status it polls anyway (``raw["inputs"]``,
``raw["outputs"]``), so watching I/O adds no bus traffic. What each terminal is set to do
(home switch, limit, alarm output, general-purpose output) is read from the drive on
request (``io_points``). An output can be switched over Modbus only where the manual
documents it; elsewhere ``set_output`` is ``NotSupported`` naming the drive and why.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

__all__ = ["IOPoint", "decode_bits"]


@dataclass(frozen=True)
class IOPoint:
    """One terminal of a drive: its name, whether it is an output, what it is set to do,
    and whether Modbus can switch it."""

    name: str
    output: bool
    function: str = ""
    """What the drive's configuration makes of it ("home switch", "alarm", ...)."""
    settable: bool = False
    """An output that ``set_output`` can switch (as configured now)."""


def decode_bits(names: Sequence[str], word: object) -> dict[str, bool]:
    """``names[i]`` -> bit ``i`` of ``word`` (every name False if ``word`` is not a number)."""
    value = word if isinstance(word, int) and not isinstance(word, bool) else 0
    return {n: bool(value >> i & 1) for i, n in enumerate(names)}


def function_text(functions: Mapping[int, str], code: int) -> str:
    """The manual's name of function ``code`` (its number where the manual has none)."""
    return functions.get(code, f"function {code}")
