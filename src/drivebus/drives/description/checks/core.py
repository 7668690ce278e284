"""What every cross-check of a description uses: the names an expression may use, the
register keys, spans and targets it may name.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

from drivebus.drives.description.model import Description
from drivebus.drives.expr import FUNCTIONS, Expr, ExprError, Template

_CONTEXT_NAMES = {
    "option", "state", "last", "words", "input", "output", "home", "pulses_per_rev",
    "value", "raw", "True", "False", "None", "input_functions", "output_functions",
}


_SPACE_NAMES = ("a holding register", "an input register", "a coil", "a discrete input")
"""What a register of each address space (``Reg.space``) is, in errors."""


class CheckCore:
    """The cross-checks' common ground: the problems found so far, and whether a name,
    a register key, a span of registers or a step's target exists."""

    def __init__(self, d: Description) -> None:
        self.d = d
        self.regs = d.regs
        self.out: list[str] = []

    def _reg_key(self, where: str, key: str) -> None:
        base = key.split("[", 1)[0]
        if base not in self.regs:
            self.out.append(f"{where}: no register {base!r} (registers: {_some(self.regs)})")

    def _names(self, where: str, expr: Expr | Template | None, extra: Iterable[str] = ()) -> None:
        """Every name ``expr`` uses must be known in its context."""
        if expr is None:
            return
        d = self.d
        known = set(self.regs) | set(d.constants) | _CONTEXT_NAMES | set(FUNCTIONS) | set(extra)
        for name in sorted(expr.names - known):
            self.out.append(f"{where}: {expr.source!r} uses {name!r}, which is no register, "
                            f"constant, option or parameter")
        for path in sorted(expr.paths):
            head, _, rest = path.partition(".")
            attr = rest.split(".", 1)[0]
            if not attr:
                continue
            if head == "option" and attr not in d.options:
                self.out.append(f"{where}: {expr.source!r}: no option {attr!r} (options: "
                                f"{_some(d.options)})")
            elif head == "state" and attr not in d.state:
                self.out.append(f"{where}: {expr.source!r}: no state variable {attr!r} "
                                f"(declare it in [state])")
            elif head in ("last", "words") and attr not in self.regs:
                self.out.append(f"{where}: {expr.source!r}: no register {attr!r}")
            elif head in self.regs and head not in extra:
                reg = self.regs[head]
                if attr not in reg.d.bits and attr not in reg.d.values:
                    self.out.append(f"{where}: {expr.source!r}: register {head} has no bit "
                                    f"or value {attr!r}")

    def _span(self, where: str, item: str | list[str]) -> None:
        keys = [item] if isinstance(item, str) else item
        if isinstance(item, list) and len(item) != 2:
            self.out.append(f"{where}: a span is [first, last] register")
        if isinstance(item, list) and self.d.link.map == "objects":
            self.out.append(f"{where}: an object-addressed map reads each object by itself: "
                            f"list the registers, not a span")
        for k in keys:
            self._reg_key(where, k)
        ends = [self.d.regs.get(k.split("[", 1)[0].strip()) for k in keys]
        if isinstance(item, list) and len(ends) == 2 and None not in ends:
            first, last = ends
            assert first is not None and last is not None
            if first.space != last.space:
                self.out.append(
                    f"{where}: a span reads one address space; {first.key} is "
                    f"{_SPACE_NAMES[first.space]} and {last.key} {_SPACE_NAMES[last.space]}")

    def _target(self, where: str, key: str, params: set[str], *, writes: bool = False
                ) -> None:
        """A register a step names: ``key`` or ``key[index expression]`` (with ``writes``:
        one the drive takes writes to)."""
        m = re.fullmatch(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[(.+)\])?", key.strip())
        if m is None:
            self.out.append(f"{where}: {key!r} is not a register (KEY or KEY[index])")
            return
        base, index = m.groups()
        if base not in self.regs:
            self.out.append(f"{where}: no register {base!r} (registers: {_some(self.regs)})")
            return
        reg = self.regs[base]
        if writes and (reg.d.access == "R" or reg.space in (1, 3)):
            self.out.append(f"{where}: register {base} is read-only (access = \"R\", an input "
                            "register or a discrete input): a procedure cannot write it")
            return
        if index is None and reg.array:
            self.out.append(f"{where}: register {base} is a table: name an entry, "
                            f"{base}[index]")
        if index is not None:
            if not reg.array:
                self.out.append(f"{where}: register {base} is not a table")
            try:
                self._names(f"{where}", Expr.parse(index), params)
            except ExprError as exc:
                self.out.append(f"{where}: {exc}")


def _some(keys: Iterable[str], n: int = 12) -> str:
    ks = list(keys)
    return ", ".join(ks[:n]) + (", ..." if len(ks) > n else "") if ks else "none"
