"""A simulated twin built from a drive description: any described drive on ``sim://``.

The twin answers only the addresses the description documents (exception 02 elsewhere,
or its ``refusals``), refuses writes to read-only registers and values outside their
ranges with the codes the description gives, reads only with the function codes its
link lists, and acts on the writes its ``[twin]`` section describes (``on_write``
triggers: moves, speed runs, stops, homing, enable, alarm clear, zeroing, save, factory
reset) with the simulator's kinematics. Status registers and bits are computed from what
they *mean* (``means``: enabled, moving, in position, homed, alarm, position, velocity,
inputs, ...); inputs carry the home and limit switches as the description's ``[inputs]``
wiring says. Limit switches stop motion and block starts towards them; an alarm stops
the motor at once; a power cycle reloads registers from the twin's EEPROM (what a save
or a write-through stored) and the defaults of volatile registers, applies a changed
line format, starts the position counter at 0 and forgets the homed state.

Homing follows the CiA 402 method each of the description's methods names (``cia402``):
17/18 (limit switches), 19-30 (home switch, with a dog of ``home_switch_width`` or a
cam), 33-37 (the present position); the position at the origin edge becomes the offset.
The home cam covers the side the method in use searches towards (``home_cam`` names the
side instead). A limit switch the method does not reverse on stops the motor as the
description's ``[twin] limits`` say, and the homing fails (``homing_failed``).

With ``soft_address`` (where ``[link] address_register`` names the register), the twin's
address is that register's saved value from the next power-up on, as ``drivebus
commission`` sets it.

The twin in rooms: ``base`` (its state: the map, stored words, line settings, units,
the counter), ``switches``, ``registers`` (reads and writes), ``triggers`` (what a
write does, the expressions), ``motion`` (moves, limits, the twin's time), ``homing``
(by CiA 402 method), ``reference`` (reference-edge, hard-stop and offset homing),
``tables``, ``io`` (terminals), ``power`` (alarms, power, line settings); ``drive``
puts them together as ``DescribedDrive``; ``cia402`` is the CiA 402 variant. This
module makes the twin class of a description (``twin_of``).
"""

from __future__ import annotations

from typing import Any

from drivebus.drives.description import Description, Reg, Trigger
from drivebus.drives.registers import Access
from drivebus.errors import ConfigError
from drivebus.pdu import READ_HOLDING, READ_INPUT
from drivebus.sim.described.cia402 import DescribedCia402Drive
from drivebus.sim.described.drive import DescribedDrive
from drivebus.sim.described.state import _Word
from drivebus.sim.registers import ExceptionCodes, RegisterSpec

__all__ = ["DescribedCia402Drive", "DescribedDrive", "described_twin", "twin_of"]


def _map(d: Description, *, inputs: bool = False
         ) -> tuple[dict[int, RegisterSpec], dict[int, _Word], dict[int, tuple[Reg, int | None]]]:
    """The twin's map of holding registers (or of input registers)."""
    specs: dict[int, RegisterSpec] = {}
    words: dict[int, _Word] = {}
    pairs: dict[int, tuple[Reg, int | None]] = {}
    for reg in d.regs.values():
        if reg.space != (1 if inputs else 0):  # coils and discrete inputs: _bits
            continue
        access = Access(reg.d.access)
        for index in (reg.indices if reg.array else [None]):
            r = reg.at(index)
            if r.words == 1:
                lo = r.lo
                hi = r.hi
                specs[r.address] = RegisterSpec(reg.default_at(index) & 0xFFFF, lo, hi, access,
                                                signed=r.signed, stored=reg.d.eeprom)
                words[r.address] = _Word(reg, index, 0)
                continue
            low = r.low_address if r.low_address is not None else r.address + 1
            for n, a in enumerate((r.address, low)):
                specs[a] = RegisterSpec(0, 0, 0xFFFF, access, stored=reg.d.eeprom)
                words[a] = _Word(reg, index, n)
                pairs[a] = (reg, index)
    return specs, words, pairs


def described_twin(d: Description) -> type[DescribedDrive]:
    """The twin class of description ``d``."""
    if d.link.map == "objects":
        raise ConfigError(f"{d.family}: the generic twin serves a flat word map only; an "
                          f"object-addressed map ([link] map = \"objects\") runs against "
                          f"its drive or an emulator of it")
    specs, words, pairs = _map(d)
    input_specs, input_words, _ = _map(d, inputs=True)
    r = d.link.refusals
    codes = ExceptionCodes(function=r.function, address=r.address, access=r.access,
                           value=r.value, count=r.count, crc=r.crc, read_access=r.read_access)
    reads = frozenset(f for f in (READ_HOLDING, READ_INPUT) if f in d.link.functions)
    triggers: dict[str, list[Trigger]] = {}
    for trig in d.twin.on_write:
        triggers.setdefault(trig.reg, []).append(trig)
    attrs: dict[str, Any] = {
        "__doc__": f"Simulated {d.family}, played from its description.",
        "__module__": __name__,
        "description": d,
        "family": d.family,
        "register_map": specs,
        "exception_codes": codes,
        "read_functions": reads,
        "max_read": d.link.max_read,
        "_map_end": max(specs, default=0),
        "_words": words,
        "_pairs": pairs,
        "_input_specs": input_specs,
        "_input_words": input_words,
        "_bits": {(reg.space, reg.at(i).address): _Word(reg, i, 0) for reg in d.regs.values()
                  if reg.space in (2, 3) for i in (reg.indices if reg.array else [None])},
        "_triggers": {k: tuple(v) for k, v in triggers.items()},
    }
    name = "Sim" + "".join(c if c.isalnum() else "_" for c in d.family)
    base: type[DescribedDrive] = DescribedDrive
    if d.drive.engine == "cia402":
        base = DescribedCia402Drive
        attrs["_objects"] = dict(d.objects)
    return type(name, (base,), attrs)


_described: dict[int, tuple[Description, type[DescribedDrive]]] = {}


def twin_of(d: Description) -> type[DescribedDrive]:
    """The twin class of description ``d`` (one class per description, made once)."""
    cached = _described.get(id(d))
    if cached is None or cached[0] is not d:
        cached = (d, described_twin(d))
        _described[id(d)] = cached
    return cached[1]
