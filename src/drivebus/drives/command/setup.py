"""Learn and setup: the reads decoding needs (``learn``, never a write), the writes of
``setup``, and the volatile settings a drive may lose.
"""

from __future__ import annotations

from drivebus.bus import Priority
from drivebus.drives.command.base import ProfileBase
from drivebus.drives.command.reads import OBJECT, plan_reads
from drivebus.drives.command.runs import _Item, _Run
from drivebus.drives.registers import Register


class Setup(ProfileBase):
    """Learn, setup and the volatile settings."""

    async def learn(self, *, priority: Priority = Priority.CONFIG) -> None:
        """Read what decoding needs (the description's ``learn`` reads, at ``priority``);
        never writes."""
        proc = self._steps_of("learn")
        if proc is not None:
            run = _Run("learn", {}, False, priority)
            await self._steps(proc.steps, run)
            self.learned.update(run.values)
        self._learned = True

    async def setup(self) -> None:
        """The description's ``setup`` writes (before the first command), then ``learn``."""
        self._learned = False
        self.homed_here = False  # set up anew (a power loss): the position is not homed
        if self._steps_of("setup") is not None:
            await self._run("setup", {})
        if not self._learned:  # unless setup called it where the drive needs it
            await self.learn()

    def volatile_settings(self) -> list[tuple[Register, int]]:
        """The (register, value) pairs of the setup steps marked volatile."""
        return [(it.register, it.raw) for it in self._volatile_items()]

    def _volatile_items(self) -> list[_Item]:
        proc = self._steps_of("setup")
        if proc is None:
            return []
        out: list[_Item] = []
        run = _Run("setup", {}, True, Priority.CONFIG)
        for step in proc.steps:
            if step.when is not None and not step.when(self._scope(run)):
                continue
            if step.action == "write" and step.volatile:
                out.extend(self._items(step, run))
        return out

    async def lost_settings(self, *, priority: Priority = Priority.COMMAND) -> list[str]:
        """The volatile settings the drive no longer holds, each read back with its address
        space's function code (a coil with FC01, an input register never: it is not
        written); holding registers as every profile reads them."""
        items = self._volatile_items()
        if all(it.reg.space == 0 for it in items):
            return await super().lost_settings(priority=priority)
        link = self.description.link
        plan = plan_reads([(it.reg, it.index) for it in items], max_read=link.max_read,
                          max_hole=0)
        words = await self._read_words(plan, priority)
        lost = []
        for it in items:
            r, base = it.register, it.reg.space << 16
            if r.objects:
                base, addresses = OBJECT + (r.address << 8) + r.offset, list(range(r.words))
            else:
                addresses = [r.address] if r.words == 1 else \
                    [r.address, r.low_address if r.low_address is not None else r.address + 1]
            seen = r.decode([words[base + a] for a in addresses])
            if seen != it.raw:
                lost.append(f"{r.name} ({r.address}) = {seen}, not {it.raw}")
        return lost
