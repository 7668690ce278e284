"""A described twin's input and output terminals: inputs driven from outside
(``set_input``), the input functions ``[twin] on_input`` acts on, and the words the
inputs' and outputs' registers show.
"""

from __future__ import annotations

from drivebus.errors import ConfigError
from drivebus.sim.described.base import TwinBase
from drivebus.sim.drive import time_or_present


class Terminals(TwinBase):
    """Input and output terminals and the input functions' edges."""

    def set_input(self, terminal: int | str, closed: bool, now: float | None = None) -> None:
        """Drive an input terminal from outside (a sensor or a PLC wired to it): its bit
        number in the inputs' state register (counted from ``[inputs] first``: IN1 = 1
        where the manual numbers so), or its name in ``[inputs] names``. The
        state register shows the terminal closed whatever the inversion register says
        (it inverts what a closed terminal means to the drive's functions); the
        switches given in the setup stay as they are."""
        io = self.description.inputs
        names = list(io.names) if io is not None else []
        reg = self.description.regs[io.state] if io is not None else None
        count = len(names) or (16 * reg.d.words if reg is not None else 0)
        first = io.first if io is not None else 0
        index = terminal - first if isinstance(terminal, int) and \
            not isinstance(terminal, bool) else terminal
        if isinstance(terminal, str):
            upper = [n.upper() for n in names]
            index = upper.index(terminal.upper()) if terminal.upper() in upper else -1
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < count:
            shown = f"{names[0]}..{names[-1]}" if names else f"{first}..{count - 1 + first}"
            raise ConfigError(f"input {terminal!r}: the simulated {self.family} has "
                              f"{f'inputs {shown}' if count else 'no inputs'}")
        bit = 1 << index
        t = time_or_present(now)
        self.advance(t)
        self._external = self._external | bit if closed else self._external & ~bit
        self._functions_changed(t)

    def _input_functions(self, now: float) -> dict[str, bool]:
        """Whether each input function an ``on_input`` trigger watches is active now."""
        if not self.description.twin.on_input:
            return {}
        p = self._phys(now)
        return {trig.input: self._signal_at(trig.input, p)
                for trig in self.description.twin.on_input}

    def _functions_changed(self, now: float) -> None:
        """Act on the input functions that turned active (or inactive) since last seen."""
        before = self._functions_seen
        after = self._input_functions(now)
        self._functions_seen = after
        for trig in self.description.twin.on_input:
            name = trig.input
            if before.get(name) == after[name] or after[name] != (trig.edge == "rise"):
                continue
            if trig.when is not None and not self._eval(trig.when, now):
                continue
            self._do(trig, None, now)

    def _io_word(self, which: str, now: float) -> int:
        d = self.description
        io = d.inputs if which == "inputs" else d.outputs
        if io is None:
            return 0
        if which == "inputs" and d.twin.wiring:  # the terminals' levels (polarity register)
            p = self._phys(now)
            return sum(1 << i for i in self._terminals()
                       if self._physical(i, p) != self._inverted(i, by_function=False))
        signals = self._signals(now)
        active = {k: v for k, v in signals.items()}
        word = 0
        if io.functions is not None:
            reg = d.regs[io.functions]
            by_code = {c: s for s, c in io.codes.items()}
            switched = self._raw(d.regs[io.values], None) if io.values is not None else 0
            for n, i in enumerate(reg.indices):
                code = self._raw(reg, i) & io.function_mask
                if io.values is not None and code == io.settable:
                    word |= (switched >> n & 1) << n  # switched over Modbus
                    continue
                sig = by_code.get(code)
                if sig is not None and active.get(sig, False):
                    word |= 1 << n
        for sig, bit in io.bits.items():
            if active.get(sig, False):
                word |= 1 << bit
        if io.invert is not None:
            word ^= self._raw(d.regs[io.invert], None)
        if which == "inputs":
            word |= self._external  # a terminal closed from outside reads closed
        return word
