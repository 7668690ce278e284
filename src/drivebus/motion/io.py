"""AxisIO: an axis's digital inputs and outputs by name (mixed into ``Axis``).

The states come from the status the actor polls anyway (no extra traffic); the names are
the drive's terminals (``IN1``, ``X3``, ``OUT2``...) or the machine file's own names for
them (``io = { vacuum = "OUT1", part_present = "IN4" }`` on the axis). Waiting for an
input makes the actor poll fast until it is seen; switching an output goes through the
axis's command lane and is read back.
"""

from __future__ import annotations

import anyio

from drivebus import checks
from drivebus.drives.io import IOPoint
from drivebus.errors import ArgumentError, InputTimeout, NotSupported
from drivebus.motion.lane import CommandLane

__all__ = ["AxisIO"]


class AxisIO(CommandLane):
    """Digital I/O of an axis's drive, by name."""

    def _terminal(self, name: str, *, output: bool) -> str:
        """The drive's terminal called ``name`` (or the machine file's name for it)."""
        terminals = self.profile.io_outputs if output else self.profile.io_inputs
        kind = "output" if output else "input"
        if not terminals:
            raise NotSupported(f"axis {self.name}: the {self.profile.family} drive has no "
                               f"{kind}s readable over Modbus")
        if not isinstance(name, str):
            raise ArgumentError(f"axis {self.name}: {kind} name: expected a string, not "
                                f"{name!r}")
        terminal = self.config.io.get(name, name)
        for t in terminals:
            if t.lower() == terminal.lower():
                return t
        named = [f"{alias} ({t})" for alias, t in self.config.io.items() if t in terminals]
        raise ArgumentError(f"axis {self.name}: no {kind} {name!r} (the "
                            f"{self.profile.family}'s {kind}s: {', '.join(terminals)}"
                            f"{'; named: ' + ', '.join(named) if named else ''})")

    def _io(self) -> tuple[dict[str, bool], dict[str, bool]]:
        st = self.status
        if st is None:
            return {}, {}
        inputs, outputs = self.profile.io_state(st)
        for alias, terminal in self.config.io.items():
            if terminal in inputs:
                inputs[alias] = inputs[terminal]
            elif terminal in outputs:
                outputs[alias] = outputs[terminal]
        return inputs, outputs

    @property
    def inputs(self) -> dict[str, bool]:
        """The drive's inputs as last polled: terminal (and machine-file name) -> active
        (empty before the first poll, or if the drive reports none)."""
        return self._io()[0]

    @property
    def outputs(self) -> dict[str, bool]:
        """The drive's outputs as last polled, likewise."""
        return self._io()[1]

    async def io_points(self) -> list[IOPoint]:
        """Every terminal of the drive and what it is set to do (read from the drive)."""
        return await self.profile.io_points()

    async def wait_input(self, name: str, state: bool = True, *,
                         timeout: float | None = None) -> None:
        """Return once input ``name`` is ``state`` in a status polled from now on (the
        actor polls fast meanwhile); ``InputTimeout`` after ``timeout`` seconds."""
        terminal = self._terminal(name, output=False)
        if timeout is not None:
            timeout = checks.positive(f"axis {self.name}: timeout", timeout, unit="s")
        self._waiters += 1
        self._poke_now()
        try:
            with anyio.fail_after(timeout):
                async for st in self.watch():
                    if self.profile.io_state(st)[0].get(terminal) == bool(state):
                        return
        except TimeoutError:
            raise InputTimeout(
                f"axis {self.name}: input {name} was not {'on' if state else 'off'} within "
                f"{timeout:g} s") from None
        finally:
            self._waiters -= 1

    async def set_output(self, name: str, state: bool) -> None:
        """Switch output ``name`` on (True) or off, where the drive lets Modbus drive it
        (``NotSupported`` naming the drive and why otherwise); returns once a status read
        after it shows it."""
        terminal = self._terminal(name, output=True)
        if not isinstance(state, bool):
            raise ArgumentError(f"axis {self.name}: output {name}: state must be true or "
                                f"false, not {state!r}")
        self.profile.check_supported("set_output")

        async def io() -> None:
            await self.profile.check_output(terminal, state)  # reads only: refused here
            await self.set_up_if_due()
            await self.profile.set_output(terminal, state)
            st = await self.refresh()
            if self.profile.io_state(st)[1].get(terminal) != state:
                raise NotSupported(f"axis {self.name}: the {self.profile.family} drive took "
                                   f"output {name} = {state} but reports it "
                                   f"{'off' if state else 'on'} (its polarity setting?)")

        await self._exclusive(io, setup_first=False)
