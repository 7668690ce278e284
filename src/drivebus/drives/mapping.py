"""Where a description's registers sit on the wire: the names of an address range (said
in Modbus exceptions) and the blocks a write may merge into one request.

A write never merges registers the manual keeps apart: a step's ``block`` and
``[cia402] blocks`` say which registers form one block, and the checks refuse a block
whose registers do not follow on from each other.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from drivebus.drives.description import Description, Reg

__all__ = ["FUNCTION_SPACE", "adjacent", "names_at", "register_namer"]

FUNCTION_SPACE = {1: 2, 5: 2, 15: 2, 2: 3, 3: 0, 6: 0, 16: 0, 4: 1}
"""The address space (``Reg.space``) each function code reads or writes."""


def names_at(d: Description, space: int, first: int, count: int) -> list[str]:
    """The names of ``d``'s registers with a word in ``first .. first + count - 1`` of
    address ``space``, in address order (a table's entries by their own names)."""
    hits: list[tuple[int, str]] = []
    last = first + max(count, 1) - 1
    for reg in d.regs.values():
        if reg.space != space:
            continue
        for index in reg.indices if reg.array else [None]:
            r = reg.at(index)
            words = [r.address] if r.words == 1 or r.objects else \
                [r.address, r.low_address if r.low_address is not None else r.address + 1]
            if any(first <= a <= last for a in words):
                hits.append((r.address, r.name))
    return [name for _, name in sorted(hits)]


def register_namer(d: Description) -> Callable[[int, int, int], str]:
    """``(function, first address, count) -> names``: what a slave handle says in a
    Modbus exception about the registers a request named."""
    def names(function: int, first: int, count: int) -> str:
        space = FUNCTION_SPACE.get(function)
        if space is None:
            return ""
        found = names_at(d, space, first, count)
        return ", ".join(found) if found else "no register of the description"
    return names


def adjacent(regs: Sequence[Reg | tuple[Reg, int | None]]) -> tuple[str, str] | None:
    """The first two registers (in the order given) where the next does not follow on
    from the one before (``Register.follows``: the next address of a flat map, the next
    words of the same object of an object-addressed one), so that one FC16 cannot write
    them; None if they follow on."""
    pairs: list[tuple[Reg, int | None]] = [
        r if isinstance(r, tuple) else (r, None) for r in regs]
    for (a, ia), (b, ib) in itertools.pairwise(pairs):
        if not (a.space == b.space == 0 and b.at(ib).follows(a.at(ia))):
            return (_label(a, ia), _label(b, ib))
    return None


def _label(reg: Reg, index: int | None) -> str:
    r = reg.at(index)
    key = reg.key if index is None else f"{reg.key}[{index}]"
    at = f", offset {r.offset}" if r.offset else ""
    kind = "object " if r.objects else ""
    return (f"{key} ({kind}{r.address}, 0x{r.address:04X}{at}, {r.words} "
            f"word{'s' * (r.words > 1)})")
