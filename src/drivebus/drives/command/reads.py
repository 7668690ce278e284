"""Read plans: which registers a read covers and in which transactions (as few as the
link's ``max_read`` and ``max_hole`` allow, spans given whole, a listed poll in its
order), and the plans a description's status poll and identity read use.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, replace

from drivebus.drives.description import Description, Reg
from drivebus.drives.expr import Expr
from drivebus.drives.registers import Register
from drivebus.errors import ConfigError

INPUT = 1 << 16
"""Where input registers' words sit in a read's words (``INPUT + address``)."""


OBJECT = 1 << 40
"""Where an object-addressed map's words sit in a read's words (``OBJECT + (address << 8)
+ word``): objects at consecutive addresses do not share words."""


_TARGET = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[(.+)\])?")


@dataclass(frozen=True)
class ReadPlan:
    """Which registers to read and in which transactions."""

    blocks: tuple[tuple[int, int], ...]
    """(first address, count) per FC03."""
    regs: tuple[tuple[Reg, int | None], ...]
    """(register, table index) read, each decoded from the blocks' words."""
    input_blocks: tuple[tuple[int, int], ...] = ()
    """(first address, count) per FC04, for input registers."""
    coil_blocks: tuple[tuple[int, int], ...] = ()
    """(first address, count) per FC01, for coils."""
    discrete_blocks: tuple[tuple[int, int], ...] = ()
    """(first address, count) per FC02, for discrete inputs."""
    space_order: tuple[int, ...] = (0, 1, 2, 3)
    """The address spaces in the order they are read (a listed poll: as listed)."""
    object_blocks: tuple[tuple[int, int], ...] = ()
    """(object address, count) per FC03 of an object-addressed map: each object read by
    itself, with its address (with the holding registers)."""


Span = tuple[int, int, int]
"""A read given whole: (address space, first address, last address); the spaces as
``Reg.space`` numbers them (0 holding, 1 input registers, 2 coils, 3 discrete inputs)."""


def plan_reads(
    targets: Iterable[tuple[Reg, int | None]], *, max_read: int, max_hole: int,
    spans: Iterable[Span] = (),
) -> ReadPlan:
    """Cover ``targets`` (and the address ``spans`` given whole, each in its own address
    space) with as few reads as ``max_read`` registers per read and gaps of at most
    ``max_hole`` allow."""
    spaces: tuple[set[int], ...] = (set(), set(), set(), set())
    wanted, inputs = spaces[0], spaces[1]
    objects: dict[int, int] = {}
    regs = []
    for reg, index in targets:
        r = reg.at(index) if reg.array else reg.register
        if r.objects:  # its object by itself, through its last word
            objects[r.address] = max(objects.get(r.address, 0), r.offset + r.words)
            regs.append((reg, index))
            continue
        space = spaces[reg.space]
        space.add(r.address)
        if r.words == 2:
            space.add(r.low_address if r.low_address is not None else r.address + 1)
        regs.append((reg, index))
    for space_no, first, last in spans:
        spaces[space_no].update(range(first, last + 1))
    return ReadPlan(_blocks(wanted, max_read, max_hole), tuple(regs),
                    _blocks(inputs, max_read, max_hole), _blocks(spaces[2], max_read, max_hole),
                    _blocks(spaces[3], max_read, max_hole),
                    object_blocks=tuple(sorted(objects.items())))


def _blocks(addresses: set[int], max_read: int, max_hole: int) -> tuple[tuple[int, int], ...]:
    blocks: list[tuple[int, int]] = []
    for a in sorted(addresses):
        if blocks:
            start, count = blocks[-1]
            end = start + count  # next address after the block
            if a - end <= max_hole and a - start + 1 <= max_read:
                blocks[-1] = (start, a - start + 1)
                continue
        blocks.append((a, 1))
    return tuple(blocks)


def _status_plan(d: Description) -> ReadPlan:
    s = d.status
    link = d.link
    if s.poll:  # read in the order listed
        return _plan(d, list(s.poll), link.max_read, link.max_hole, listed=True)
    names: set[str] = set()
    for e in (*d.status_exprs.values(), *s.raw.values(), *s.track.values()):
        names |= e.names
    for io in (d.inputs,):
        if io is not None and {"input"} & names:
            names.add(io.state)
            if io.invert is not None:
                names.add(io.invert)
    learned = _learned_keys(d)
    items: list[str | list[str]] = sorted(n for n in names if n in d.regs and n not in learned)
    return _plan(d, items, link.max_read, link.max_hole)


def _learned_keys(d: Description) -> set[str]:
    proc = d.procedures.get("learn")
    out: set[str] = set()
    if proc is None:
        return out
    for step in proc.steps:
        for item in step.read or []:
            if isinstance(item, str):
                out.add(item.split("[", 1)[0])
    return out


def _plan(d: Description, items: Sequence[str | list[str]], max_read: int,
          max_hole: int, listed: bool = False) -> ReadPlan:
    targets: list[tuple[Reg, int | None]] = []
    spans: list[Span] = []
    regs = d.regs
    for item in items:
        if isinstance(item, list):
            first = _static_target(d, item[0])
            last = _static_target(d, item[1])
            span = (regs[_item_key(item)].space, first.address,
                    last.low_address if last.low_address is not None else
                    last.address + last.words - 1)
            spans.append(span)
            targets.extend(_in_span(regs.values(), span))
        else:
            reg = regs[item.split("[", 1)[0]]
            targets.extend((reg, i) for i in (reg.indices if reg.array else [None]))
    plan = plan_reads(targets, max_read=max_read, max_hole=max_hole, spans=spans)
    return _in_listed_order(plan, [(d.regs[_item_key(i)], i) for i in items]) if listed \
        else plan


def _in_span(regs: Iterable[Reg], span: Span) -> Iterator[tuple[Reg, int | None]]:
    """The registers (and table entries) of ``span``'s address space within its
    addresses: a span of discrete inputs reads no holding register of the same numbers."""
    space, first, last = span
    for reg in regs:
        if reg.space != space:
            continue
        for index in (reg.indices if reg.array else [None]):
            if first <= reg.at(index).address <= last:
                yield reg, index


def _item_key(item: str | list[str]) -> str:
    return (item[0] if isinstance(item, list) else item).split("[", 1)[0].strip()


def _in_listed_order(plan: ReadPlan, listed: Sequence[tuple[Reg, str | list[str]]]
                     ) -> ReadPlan:
    """``plan`` with its reads of each kind, and the kinds (FC03, FC04, FC01, FC02), in the
    order their registers are listed (a drive whose status takes several reads: the poll
    reads its motion state before the position, so a position read after the drive has
    come to rest is its final one, its motion state a discrete input or not)."""
    def rank(blocks: tuple[tuple[int, int], ...], space: int) -> tuple[tuple[int, int], ...]:
        def first_listed(block: tuple[int, int]) -> int:
            start, count = block
            for n, (reg, _) in enumerate(listed):
                if reg.space == space and start <= reg.register.address < start + count:
                    return n
            return len(listed)
        return tuple(sorted(blocks, key=first_listed))
    order = list(dict.fromkeys(reg.space for reg, _ in listed))
    return replace(
        plan, blocks=rank(plan.blocks, 0), input_blocks=rank(plan.input_blocks, 1),
        coil_blocks=rank(plan.coil_blocks, 2), discrete_blocks=rank(plan.discrete_blocks, 3),
        space_order=(*order, *(s for s in (0, 1, 2, 3) if s not in order)))


def _static_target(d: Description, key: str) -> Register:
    m = _TARGET.fullmatch(key.strip())
    if m is None:
        raise ConfigError(f"{d.family}: {key!r} is not a register")
    reg = d.regs[m.group(1)]
    return reg.at(int(m.group(2), 0)) if m.group(2) is not None else reg.register


@functools.lru_cache(maxsize=1024)
def parsed_target(key: str) -> tuple[str, Expr | None]:
    """A write target ``register`` or ``register[index expression]``, parsed once (a move
    writes the same few again and again)."""
    m = _TARGET.fullmatch(key.strip())
    assert m is not None  # checked when the description was loaded
    return m.group(1), None if m.group(2) is None else Expr.parse(m.group(2))
