"""The status poll's decoding worked out once per profile: each register's words, codec
and conversion, the plain and linear ones (pulses, rpm, r/s²) as one multiplication.
It gives what ``Status._decode`` gives for the same words (tests/test_status_decoding.py).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from drivebus.drives.command.reads import OBJECT, ReadPlan
from drivebus.drives.description import Description
from drivebus.drives.units import Kind
from drivebus.drives.values import RegValue, Table, reg_value


class Decoding:
    """A read plan's decoding made once (what ``_decode_one`` finds out afresh per
    register and poll). The status poll runs it."""

    __slots__ = ("plan", "ppr", "steps")

    def __init__(self, plan: ReadPlan, ppr: int) -> None:
        self.plan = plan
        self.ppr = ppr
        steps = []
        ordered = [ri for ri in plan.regs if ri[0].codec.kind is not Kind.RAMP] + \
            [ri for ri in plan.regs if ri[0].codec.kind is Kind.RAMP]
        for reg, index in ordered:
            r = reg.at(index)
            base = reg.space << 16  # as _decode_one finds its words
            if r.objects:
                at = OBJECT + (r.address << 8) + r.offset
                addresses = tuple(at + j for j in range(r.words))
            elif r.words == 2:
                low = r.low_address if r.low_address is not None else r.address + 1
                addresses = (base + r.address, base + low)
            else:
                addresses = (base + r.address,)
            codec = reg.codec
            mode = 0  # 0: the codec converts; 1: raw as it is; 2: raw * scale * factor
            factor = 1.0
            if codec.kind in (Kind.PLAIN, Kind.NAMED):
                mode = 1
            elif codec.kind in (Kind.POSITION, Kind.SPEED, Kind.ACCEL):
                mode, factor = 2, codec.factor(ppr)
            table = index is not None and reg.array
            steps.append((reg, index, r, addresses, mode, codec.scale, factor,
                          codec.kind is Kind.POSITION, table))
        self.steps = tuple(steps)

    def decode(self, description: Description, last: Mapping[str, Any],
               words: Mapping[int, int],
               raw_words: dict[str, list[int]] | None) -> dict[str, Any]:
        """Register key -> value for the plan's words (``last``: what was last written,
        for a ramp time given against a speed the poll does not read)."""
        out: dict[str, Any] = {}
        tables: dict[str, dict[int, Any]] = {}
        for reg, index, r, addresses, mode, scale, factor, position, table in self.steps:
            ws = [words[addresses[0]]] if len(addresses) == 1 else \
                [words[a] for a in addresses]
            raw = r.decode(ws)
            if mode == 1:  # a plain or named register: its raw value, bits and names
                value: Any = RegValue(raw, reg)
            elif mode == 2:  # as UnitCodec.to_physical computes it, in the same order
                v = raw * scale * factor
                value = int(v) if position and v == int(v) else float(v)
            else:
                ref = None
                codec = reg.codec
                if codec.kind is Kind.RAMP and isinstance(codec.ramp, str):
                    ref_val = out.get(codec.ramp, last.get(codec.ramp))
                    ref = None if ref_val is None or isinstance(ref_val, Table) \
                        else float(ref_val)
                physical = codec.to_physical(raw, ppr=self.ppr, ref_rpm=ref)
                value = reg_value(reg, raw, physical)
            if table:
                tables.setdefault(reg.key, {})[index] = value
            else:
                out[reg.key] = value
                if raw_words is not None:
                    raw_words[reg.key] = ws
        for key, entries in tables.items():
            out[key] = Table(description.regs[key], entries)
        return out
