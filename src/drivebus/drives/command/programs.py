"""Motion programs and digital I/O: the terminals and their functions, a position table
prepared and started, an output set or checked.
"""

from __future__ import annotations

from collections.abc import Sequence

from drivebus.bus import Priority
from drivebus.drives.base import MoveParams
from drivebus.drives.command.base import ProfileBase
from drivebus.drives.io import IOPoint, function_text
from drivebus.drives.values import Table


class Programs(ProfileBase):
    """Digital I/O and position tables."""

    async def io_points(self) -> list[IOPoint]:
        """Every terminal of ``[inputs]``/``[outputs] names``, with the function its
        ``functions`` register assigns (read now, in as few reads as the link allows; named
        by ``function_names``, else the register's ``values``, else ``codes``) or the signal
        its fixed wiring (``bits``) carries; an output is settable when its function is
        ``[outputs] settable``."""
        d = self.description
        sides = [(io, names, output) for io, names, output in
                 ((d.inputs, self.io_inputs, False), (d.outputs, self.io_outputs, True))
                 if io is not None and names]
        keys = [io.functions for io, _, _ in sides if io.functions is not None]
        values = await self._read_items(keys, None, Priority.CONFIG) if keys else {}
        points: list[IOPoint] = []
        for io, names, output in sides:
            wired = {bit: signal.replace("_", " ") for signal, bit in io.bits.items()}
            table = values.get(io.functions) if io.functions is not None else None
            reg = d.regs[io.functions] if io.functions is not None else None
            named = reg.d.values if reg is not None and reg.d.values else io.codes
            texts = io.function_names or {c: k.replace("_", " ") for k, c in named.items()}
            for n, name in enumerate(names):
                if isinstance(table, Table) and reg is not None:
                    code = int(table[reg.indices[n]]) & io.function_mask
                    points.append(IOPoint(name, output, function_text(texts, code),
                                          output and io.settable == code))
                else:
                    points.append(IOPoint(name, output, wired.get(n, "")))
        return points

    async def prepare_table(self, rows: Sequence[tuple[int, MoveParams, float]],
                            trigger: str) -> None:
        """The description's ``prepare_table`` with ``rows`` (``rows[i]['position']``,
        ``'speed'``, ``'accel'``, ``'decel'``, ``'wait'`` in s), ``trigger`` (an input's
        name) and ``input`` (its number, from 1)."""
        if self._steps_of("prepare_table") is None:
            await super().prepare_table(rows, trigger)
            return
        table = [{"position": int(p), "speed": m.speed_rpm, "accel": m.accel_rps2,
                  "decel": m.decel_rps2, "wait": float(w)} for p, m, w in rows]
        await self.run("prepare_table", rows=table, trigger=trigger,
                       input=self.io_inputs.index(trigger) + 1)

    async def start_table(self) -> None:
        """The description's ``start_table``."""
        if self._steps_of("start_table") is None:
            await super().start_table()
            return
        await self.run("start_table")

    async def set_output(self, name: str, state: bool) -> None:
        """The description's ``set_output`` with ``output`` (the name), ``index`` (its
        number, from 1) and ``state``."""
        if self._steps_of("set_output") is None:
            await super().set_output(name, state)
            return
        await self.run("set_output", output=name, index=self.io_outputs.index(name) + 1,
                       state=bool(state))

    async def check_output(self, name: str, state: bool) -> None:
        """The refusals of the description's ``set_output`` that its reads decide (its
        read, check and fail steps before its first write), nothing written."""
        self.check_supported("set_output")
        await self.preflight("set_output", output=name,
                             index=self.io_outputs.index(name) + 1, state=bool(state))
