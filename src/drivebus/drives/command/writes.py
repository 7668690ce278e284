"""Writes: a step's targets and values, converted through each register's codec and
range-checked, then written as the link allows (FC06, FC16, word by word, a block,
only what changed, a read-modify-write).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from drivebus.bus import Priority
from drivebus.drives.command.base import ProfileBase
from drivebus.drives.command.reads import parsed_target
from drivebus.drives.command.runs import _Item, _Run
from drivebus.drives.description import Reg, Step
from drivebus.drives.expr import Expr, Unknown
from drivebus.drives.registers import Register
from drivebus.drives.units import Kind
from drivebus.drives.values import RegValue, Table, Unread
from drivebus.errors import LimitViolation


class Writes(ProfileBase):
    """Values encoded, checked and written."""

    def _target(self, key: str, scope: Mapping[str, Any]) -> tuple[Reg, int | None]:
        name, index_expr = parsed_target(key)
        reg = self.description.regs[name]
        index = None
        if index_expr is not None:
            index = index_expr(scope)
            if isinstance(index, float) and index == int(index):
                index = int(index)
            if isinstance(index, str) and index in reg.d.names:
                index = reg.d.first + reg.d.names.index(index)
        reg.at(index)  # LimitViolation for an index outside the table
        return reg, index

    def _items(self, step: Step, run: _Run) -> list[_Item]:
        """The step's writes, evaluated, converted to raw values and range-checked."""
        assert step.write is not None
        scope = self._scope(run)
        scopes = [scope]
        if step.each is not None:  # "NAME in EXPRESSION": the writes once per value
            name, _, source = step.each.partition(" in ")
            values = Expr.parse(source)(scope)  # None (an option not given): no writes
            scopes = [{**scope, name.strip(): v} for v in values or ()]
        items = []
        for each in scopes:
            for key, w in step.write.items():
                reg, index = self._target(key, each)
                value = w.value(each)
                if isinstance(value, Unread):  # a register named bare, not read yet: the
                    raise Unknown(f"register {value.key} was not read")  # drive answers it
                items.append(_Item(reg, index, reg.at(index), value, w.value, w.nonzero, w.raw))
        for item in items:  # ramp times last: they refer to the speeds written with them
            if item.reg.codec.kind is not Kind.RAMP:
                self._encode(item, items, run)
        for item in items:
            if item.reg.codec.kind is Kind.RAMP:
                self._encode(item, items, run)
        for item in items:
            run.written[item.key] = item.physical
            run.trace.append(("write", item.reg, item.index, item.raw, item.source.source))
        return items

    def _encode(self, item: _Item, items: Sequence[_Item], run: _Run) -> None:
        codec = item.reg.codec
        ref = None
        if codec.kind is Kind.RAMP and isinstance(codec.ramp, str):
            ref = self._reference(codec.ramp, item.index, items, run)
        if item.value is None:
            raise LimitViolation(f"no value for register {item.register.name} (address "
                                 f"{item.register.address}): {item.source} is not given")
        if item.as_raw:  # `raw = true`: the register's own value, range-checked only
            if isinstance(item.value, bool | str) or not isinstance(item.value, int | float):
                raise LimitViolation(f"raw value {item.value!r} for register "
                                     f"{item.register.name} is not a whole number")
            raw = item.register.check(item.value)  # type: ignore[arg-type]
        else:
            raw = codec.to_raw(item.register, item.value, ppr=self.pulses_per_rev,
                               ref_rpm=ref)
        if item.nonzero and raw == 0:
            reg = item.register
            unit = f" {reg.unit}" if reg.unit else ""
            raise LimitViolation(
                f"value {item.value} {codec.drive_unit} for register {reg.name} (address "
                f"{reg.address}) is outside its usable range {max(reg.lo, 1)}..{reg.hi}{unit} "
                f"for this command")
        item.raw = raw
        item.physical = codec.to_physical(raw, ppr=self.pulses_per_rev, ref_rpm=ref)

    def _reference(self, key: str, index: int | None, items: Sequence[_Item],
                   run: _Run) -> float | None:
        """The speed a ramp time refers to: written with it, earlier in this run, or last."""
        ref = key if index is None or not self.description.regs[key].array else \
            f"{key}[{index}]"
        for it in items:
            if it.key == ref and it.reg.codec.kind is not Kind.RAMP:
                return float(it.physical)
        if ref in run.written:
            return float(run.written[ref])
        last = self.last.get(ref)
        return None if last is None else float(last)

    async def write(self, reg: Register, value: int, *, priority: Priority = Priority.CONFIG,
                    idempotent: bool = True) -> None:
        """Write one register with the function codes the drive serves (FC06 where it has
        it, else FC16; a 32-bit value in one FC16, or word by word without FC16)."""
        fcs = self.description.link.functions
        if reg in self._coils:
            await self.slave.write_coil(reg.address, bool(reg.check(value)), priority=priority,
                                        idempotent=idempotent)
            return
        if reg.offset:  # a sub-index behind its object's address: with the words before it
            await super().write(reg, value, priority=priority, idempotent=idempotent)
            return
        words = reg.encode(value)
        if len(words) == 1 and 6 not in fcs:
            await self.slave.write_registers(reg.address, words, priority=priority,
                                             idempotent=idempotent)
            return
        if len(words) == 2 and 16 not in fcs:
            low = reg.low_address if reg.low_address is not None else reg.address + 1
            for address, word in sorted(((reg.address, words[0]), (low, words[1]))):
                await self.slave.write_register(address, word, priority=priority,
                                                idempotent=idempotent)
            return
        await super().write(reg, value, priority=priority, idempotent=idempotent)

    async def write_block(self, regs: Sequence[tuple[Register, int]], *,
                          priority: Priority = Priority.CONFIG, idempotent: bool = True) -> None:
        """Consecutive registers in as few FC16 as ``link.max_write`` allows (a 32-bit
        value is never split between two)."""
        limit = self.description.link.max_write
        chunk: list[tuple[Register, int]] = []
        for reg, value in regs:
            if chunk and sum(r.words for r, _ in chunk) + reg.words > limit:
                await super().write_block(chunk, priority=priority, idempotent=idempotent)
                chunk = []
            chunk.append((reg, value))
        if chunk:
            await super().write_block(chunk, priority=priority, idempotent=idempotent)

    async def _write(self, step: Step, run: _Run, prio: Priority) -> None:
        items = self._items(step, run)
        if step.if_changed:  # leave out what the drive already holds
            items = await self._changed(items, run, prio)
        block = step.block is not None and bool(step.block(self._scope(run))) and \
            16 in self.description.link.functions and \
            not any(it.register in self._coils for it in items)
        idem = step.idempotent
        if block:
            for group in _consecutive(items):
                await self.write_block([(it.register, it.raw) for it in group], priority=prio,
                                       idempotent=idem)
        else:
            for it in items:
                r = it.register
                if step.single and r.words == 2:
                    words = r.encode(it.raw)
                    low = r.low_address if r.low_address is not None else r.address + 1
                    for address, word in sorted(((r.address, words[0]), (low, words[1]))):
                        await self.slave.write_register(address, word, priority=prio,
                                                        idempotent=idem)
                else:
                    await self.write(r, it.raw, priority=prio, idempotent=idem)
        for it in items:
            self.last[it.key] = it.physical

    async def write_values(self, values: Mapping[str, Any], *, raw: bool = False,
                           block: bool = False,
                           priority: Priority = Priority.CONFIG) -> None:
        """Write registers (``KEY`` or ``KEY[i]`` = a physical value, or the raw value with
        ``raw``) as one write step of a procedure would: converted and range-checked
        before the first frame, in one FC16 with ``block``."""
        step = Step.model_validate({
            "write": {k: {"value": Expr.parse(repr(v) if isinstance(v, str) else v),
                          "raw": raw} for k, v in values.items()},
            **({"block": Expr.parse(True)} if block else {})})
        self._items(step, _Run("write", {}, True, priority))  # checked before any frame
        await self._write(step, _Run("write", {}, False, priority), priority)

    async def _changed(self, items: list[_Item], run: _Run, prio: Priority) -> list[_Item]:
        """The items whose raw value differs from the drive's (read in this run, else now)."""
        out = []
        for it in items:
            held = run.values.get(it.reg.key)
            if isinstance(held, Table):
                held = held.get(it.index) if it.index is not None else None
            if held is None or isinstance(held, Unread) or it.reg.codec.physical:
                current = await self.read(it.register, priority=prio)
            else:
                current = int(held)
            if current != it.raw:
                out.append(it)
        return out

    async def _modify(self, step: Step, run: _Run, prio: Priority) -> None:
        assert step.modify is not None
        scope = self._scope(run)
        reg, index = self._target(step.modify, scope)
        r = reg.at(index)
        value = await self.read(r, priority=prio)
        set_bits = int(step.bits_set(scope)) if step.bits_set is not None else 0
        clear = int(step.bits_clear(scope)) if step.bits_clear is not None else 0
        toggle = int(step.bits_toggle(scope)) if step.bits_toggle is not None else 0
        new = ((value | set_bits) & ~clear) ^ toggle
        await self.write(r, new, priority=prio, idempotent=False)
        if step.pulse:
            await self.write(r, value, priority=prio, idempotent=False)
        else:
            self.last[reg.key if index is None else f"{reg.key}[{index}]"] = new
        run.values[reg.key] = RegValue(new if not step.pulse else value, reg)


def _consecutive(items: Sequence[_Item]) -> list[list[_Item]]:
    """Items grouped into runs of registers that follow on (one FC16 each)."""
    groups: list[list[_Item]] = []
    for it in items:
        if groups and it.register.follows(groups[-1][-1].register):
            groups[-1].append(it)
            continue
        groups.append([it])
    return groups
