"""What the names of a description's expressions stand for while they are evaluated.

A register's name stands for its value: the *physical* value (pulses, rpm, r/s²) for a
register with a unit, the raw value for any other. A raw value is a ``RegValue``: an int
whose bits and named values read as attributes (``status.ENABLED`` is that bit of the
status word, ``mode.homing`` the value named ``homing``). Tables read by index
(``di_function[2]``). The context objects are ``option.NAME``, ``state.NAME``,
``last.REGISTER`` (the value last written), ``words.REGISTER`` (the raw words read),
``input.SIGNAL`` / ``output.SIGNAL`` and ``home.NAME`` (the homing method being run).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from drivebus.drives.description import Description, IoDef, Reg
from drivebus.drives.expr import ExprError, Unknown

__all__ = ["Attrs", "FunctionNames", "IoSignals", "RegValue", "Table", "Unread", "reg_value"]


class RegValue(int):
    """A raw register value whose bits and named values read as attributes."""

    _reg: Reg

    def __new__(cls, value: int, reg: Reg) -> RegValue:
        obj = super().__new__(cls, value)
        obj._reg = reg
        return obj

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        d = self._reg.d
        b = d.bits.get(name)
        if b is not None:
            field = (int(self) >> b.bit) & ((1 << b.width) - 1)
            return bool(field) if b.width == 1 else field
        if name in d.values:
            return d.values[name]
        raise ExprError(f"register {self._reg.key} has no bit or value {name!r}")

    def __eq__(self, other: object) -> bool:
        if isinstance(other, str) and other in self._reg.d.values:
            return int(self) == self._reg.d.values[other]
        return int(self) == other

    def __ne__(self, other: object) -> bool:
        return not self == other

    def __hash__(self) -> int:
        return int.__hash__(self)


class Table:
    """The values read of a table of registers, by index."""

    __slots__ = ("_reg", "_values")

    def __init__(self, reg: Reg, values: Mapping[int, Any]) -> None:
        self._reg = reg
        self._values = dict(values)

    def __getitem__(self, index: int | str) -> Any:
        if isinstance(index, str) and index in self._reg.d.names:
            index = self._reg.d.first + self._reg.d.names.index(index)
        try:
            return self._values[index]  # type: ignore[index]
        except KeyError:
            raise Unknown(f"{self._reg.key}[{index}] was not read") from None

    def get(self, index: int, default: Any = None) -> Any:
        """Entry ``index``, or ``default`` if it was not read."""
        return self._values.get(index, default)

    def __iter__(self) -> Any:
        return iter(self._values[i] for i in sorted(self._values))

    def __len__(self) -> int:
        return len(self._values)

    def items(self) -> Iterable[tuple[int, Any]]:
        """(index, value) pairs."""
        return sorted(self._values.items())


class Unread:
    """A register that was not read yet: using its value raises ``Unknown``."""

    __slots__ = ("key",)

    def __init__(self, key: str) -> None:
        self.key = key

    def _unknown(self, *_: Any) -> Any:
        raise Unknown(f"register {self.key} was not read")

    __getattr__ = __getitem__ = __int__ = __index__ = __bool__ = __float__ = _unknown
    __add__ = __radd__ = __sub__ = __rsub__ = __mul__ = __rmul__ = __and__ = __rand__ = _unknown
    __or__ = __ror__ = __lt__ = __le__ = __gt__ = __ge__ = __truediv__ = __neg__ = _unknown
    __abs__ = __rshift__ = __lshift__ = __xor__ = __mod__ = __floordiv__ = _unknown

    def __eq__(self, other: object) -> bool:
        raise Unknown(f"register {self.key} was not read")

    __ne__ = __eq__
    __hash__ = None  # type: ignore[assignment]


class Attrs:
    """Attribute access to a mapping (``option.NAME``, ``state.NAME``, ``home.NAME``);
    ``missing`` is the value of a name it lacks (``Unknown`` is raised if it is None)."""

    __slots__ = ("_missing", "_name", "_values")

    def __init__(self, name: str, values: Mapping[str, Any], missing: Any = Unknown) -> None:
        self._name = name
        self._values = values
        self._missing = missing

    def __getattr__(self, key: str) -> Any:
        if key.startswith("_"):
            raise AttributeError(key)
        try:
            return self._values[key]
        except KeyError:
            if self._missing is Unknown:
                raise Unknown(f"{self._name}.{key} is not known") from None
            return self._missing


def reg_value(reg: Reg, raw: int, physical: Any) -> Any:
    """The value a register's name stands for: a ``RegValue`` for a raw register."""
    if reg.codec.physical:
        return physical
    return RegValue(raw, reg)


_MASKS: dict[tuple[int, int, str], tuple[object, int]] = {}
"""``IoSignals._mask`` by (wiring, function table, signal), with the table it was made from:
a table is read when the drive is set up, and a poll asks for the same signals each time
(a table made afresh is a new key; the dict is emptied when it grows)."""


class IoSignals:
    """``input.NAME`` / ``output.NAME``: whether a terminal carrying signal NAME is active,
    from the terminal states, their inversion mask and their function assignments."""

    __slots__ = ("_d", "_io", "_values")

    def __init__(self, desc: Description, io_key: str, values: Mapping[str, Any]) -> None:
        self._d = desc
        self._io = getattr(desc, io_key)
        self._values = values

    def __getattr__(self, name: str) -> bool:
        if name.startswith("_"):
            raise AttributeError(name)
        io = self._io
        if io is None:
            raise ExprError(f"the description has no [{name}] wiring")
        state = self._values.get(io.state)
        if state is None or isinstance(state, Unread):
            raise Unknown(f"register {io.state} was not read")
        bits = int(state)
        if io.invert is not None:
            inv = self._values.get(io.invert)
            bits ^= int(inv) if isinstance(inv, int) else 0
        if name in io.bits:
            return bool((bits >> io.bits[name]) & 1)
        if name not in io.codes or io.functions is None:
            return False
        funcs = self._values.get(io.functions)
        key = (id(io), id(funcs), name)
        known = _MASKS.get(key)
        if known is None or known[0] is not funcs:
            known = (funcs, self._mask(io, name, funcs))
            if len(_MASKS) >= 256:
                _MASKS.clear()
            _MASKS[key] = known
        return bool(bits & known[1])

    def _mask(self, io: IoDef, name: str, funcs: object) -> int:
        """The terminals (bit n: the n-th) assigned the function of signal ``name``."""
        code = io.codes[name]
        assert io.functions is not None
        reg = self._d.regs[io.functions]
        mask = 0
        for n, index in enumerate(reg.indices):
            fn = funcs.get(index) if isinstance(funcs, Table) else None
            if fn is None:
                fn = reg.default_at(index)
            if int(fn) == code:
                mask |= 1 << n
        return mask


class FunctionNames:
    """``input_functions[code]`` / ``output_functions[code]``: the manual's name of an I/O
    function code (``function N`` where it gives none)."""

    __slots__ = ("_names",)

    def __init__(self, io: IoDef | None) -> None:
        self._names = dict(io.function_names) if io is not None else {}

    def __getitem__(self, code: int) -> str:
        return self._names.get(int(code), f"function {int(code)}")
