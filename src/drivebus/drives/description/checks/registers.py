"""The cross-checks of ``[registers]`` and ``[cia402]``: addresses that overlap or fall
outside the map, ranges and ramps, the function codes the spaces need, the objects and
their blocks, the parameters' keys.
"""

from __future__ import annotations

from drivebus.drives.description.checks.core import CheckCore
from drivebus.drives.description.objects import Cia402Def, object_name
from drivebus.drives.description.registers import RegisterDef
from drivebus.drives.expr import FUNCTIONS
from drivebus.drives.registers import Register
from drivebus.drives.units import Kind
from drivebus.errors import ConfigError


class RegisterChecks(CheckCore):
    """Registers, objects and parameters."""

    def _parameters(self) -> None:
        seen: dict[str, str] = {}
        for pkey, reg, index in self.d.parameter_regs():
            where = reg.key if index is None else f"{reg.key}[{index}]"
            other = seen.setdefault(pkey, where)
            if other != where:
                self.out.append(f"registers.{reg.key}.parameter: key {pkey!r} is also "
                                f"registers.{other}'s")

    def _registers(self) -> None:
        if not self.regs:
            self.out.append("registers: none given (a description needs at least one)")
        owner: dict[int, str] = {}
        for key, given in self.d.registers.items():
            base = self.d.register_base(given)
            for field in ("address", "low_address"):
                number = getattr(given, field)
                if number is not None and number < base:
                    self.out.append(
                        f"registers.{key}.{field}: {number} is below the first register, "
                        f"{base} (link.register_base = {self.d.link.register_base}: "
                        f"addresses are the manual's numbers)")
        for key, reg in self.regs.items():
            where = f"registers.{key}"
            d = reg.d
            if d.ramp is not None and isinstance(d.ramp, str):
                ref = self.regs.get(d.ramp)
                if ref is None:
                    self.out.append(f"{where}.ramp: no register {d.ramp!r}")
                elif ref.codec.kind is not Kind.SPEED:
                    self.out.append(f"{where}.ramp: register {d.ramp} holds no speed (give it "
                                    f"a speed unit: rpm, rps, pulses/s)")
            if d.ramp is not None and d.unit not in ("ms", "s"):
                self.out.append(f"{where}.unit: a ramp time is in 'ms' or 's', not {d.unit!r}")
            try:
                Register(reg.name, d.address, d.words, signed=d.signed, minimum=d.min,
                         maximum=d.max)
            except ConfigError as exc:
                self.out.append(f"{where}: {exc}")
            lo, hi = reg.register.lo, reg.register.hi
            if (d.min is not None and d.min < _width_lo(d)) or (d.max is not None and \
                    d.max > _width_hi(d)):
                self.out.append(f"{where}: range {lo}..{hi} does not fit {16 * d.words} "
                                f"{'signed' if d.signed else 'unsigned'} bits")
            given = [("default", d.default)] if "default" in d.model_fields_set else []
            given += [(f"defaults[{i}]", v) for i, v in enumerate(d.defaults)]
            for what, v in given:
                if not lo <= v <= hi:
                    self.out.append(f"{where}.{what}: {v} is outside the register's range "
                                    f"{lo}..{hi}")
            if d.words == 1 and d.low_address is not None:  # 1 by [link] words
                self.out.append(f"{where}.low_address: low_address is for a 32-bit register "
                                f"(words = 2)")
            for bit, b in d.bits.items():  # a register 16 bits wide by [link] words
                if b.bit + b.width > 16 * d.words:
                    self.out.append(f"{where}: bit {bit} ({b.bit}, width {b.width}) is "
                                    f"beyond the register's {16 * d.words} bits")
            self._bits_apart(where, d)
            for name, raw in d.values.items():
                if not lo <= raw <= hi:
                    self.out.append(f"{where}.values.{name}: {raw} is outside the register's "
                                    f"range {lo}..{hi}")
            if d.offset and not reg.objects:
                self.out.append(f"{where}.offset: an offset is for a sub-index of an "
                                f"object-addressed map ([link] map = \"objects\")")
            space = reg.space << 24  # inputs, coils and discrete inputs: spaces apart
            for a in reg.addresses():
                shown = a >> 8 if reg.objects else a
                if shown > 0xFFFF:
                    self.out.append(f"{where}: its words reach address {shown}, beyond 65535")
                    break
                if space + a in owner and owner[space + a] != key:
                    word = f", word {a & 0xFF} of the object" if reg.objects else ""
                    self.out.append(f"{where}.address: address {shown} (0x{shown:04X}{word}) "
                                    f"is also register {owner[space + a]}")
                    break
                owner[space + a] = key

    def _bits_apart(self, where: str, d: RegisterDef) -> None:
        """Two bits (fields) of a register may not share a bit: the manual gives each bit
        one meaning, and a status read through both would contradict itself."""
        seen: list[tuple[str, int]] = []
        for name, b in d.bits.items():
            for other, mask in seen:
                if mask & b.mask:
                    self.out.append(f"{where}.bits.{name}: it shares bit(s) "
                                    f"{_bit_list(mask & b.mask)} with bits.{other}")
                    break
            seen.append((name, b.mask))

    def _names_apart(self) -> None:
        """Errors and logs name a register by its display name: two registers may not
        share one."""
        owner: dict[str, str] = {}
        for key, reg in self.regs.items():
            shown = reg.name.casefold()
            other = owner.setdefault(shown, key)
            if other != key:
                where = f"registers.{key}.name" if reg.d.name else f"registers.{key}"
                self.out.append(f"{where}: the name {reg.name!r} is also register {other}'s "
                                f"(errors name a register by it: give each its own)")

    def _cia402(self) -> None:
        d = self.d
        for key, r in d.registers.items():
            if r.object is not None and object_name(r.object) is None:
                self.out.append(f"registers.{key}.object: {r.object!r} is not a CiA 402 "
                                f"object drivebus knows (see drivebus.drives.cia402.OBJECTS)")
        c = d.cia402
        if c is not None:
            for i, ref in enumerate(c.objects):
                if object_name(ref) is None:
                    self.out.append(f"cia402.objects[{i}]: {ref!r} is not a CiA 402 object")
            if c.objects and c.address_rule is None:
                self.out.append("cia402.objects: needs address_rule (how an object's index "
                                "and sub-index give its address)")
            self._cia402_blocks(c)
            if c.address_rule is not None:
                unknown = c.address_rule.names - {"index", "sub"} - set(FUNCTIONS)
                if unknown:
                    self.out.append(f"cia402.address_rule: {c.address_rule.source!r} may use "
                                    f"only index and sub, not {', '.join(sorted(unknown))}")
                self._placed_overlaps()
        spaces = {r.space for r in self.regs.values()}
        for space, fc, what in ((0, 3, "holding registers"), (1, 4, "input registers"),
                                (2, 1, "coils"), (3, 2, "discrete inputs")):
            if space in spaces and fc not in d.link.functions:
                self.out.append(f"link.functions: {what} need function code {fc}")
        if d.link.map == "objects" and 16 not in d.link.functions and any(
                r.d.words == 2 or r.d.offset for r in self.regs.values()):
            self.out.append("link.functions: an object-addressed map writes a 32-bit object "
                            "or a sub-index with function code 16 (its words go with its one "
                            "address)")
        if any(r.d.coil and r.d.access != "R" for r in self.regs.values()) and \
                5 not in d.link.functions:
            self.out.append("link.functions: writing coils needs function code 5")
        if d.drive.engine == "cia402":
            for needed in ("controlword", "statusword"):
                if needed not in d.objects:
                    self.out.append(f"registers: the CiA 402 engine needs the {needed} "
                                    f"(a register with object = \"{needed}\")")
        elif c is not None:
            self.out.append("cia402: only for drive.engine = \"cia402\"")

    def _cia402_blocks(self, c: Cia402Def) -> None:
        from drivebus.drives.description.mapping import adjacent

        seen: dict[str, int] = {}
        for i, block in enumerate(c.blocks):
            regs = []
            for ref in block:
                name = object_name(ref)
                if name is None or name not in self.d.objects:
                    self.out.append(f"cia402.blocks[{i}]: {ref!r} is no object mapped to a "
                                    f"register")
                    return
                if name in seen:
                    self.out.append(f"cia402.blocks[{i}]: {name} is also in "
                                    f"cia402.blocks[{seen[name]}]")
                seen[name] = i
                regs.append(self.d.objects[name])
            gap = adjacent(regs)
            if gap is not None:
                self.out.append(f"cia402.blocks[{i}]: {gap[0]} and {gap[1]} are not "
                                f"adjacent, so one FC16 cannot write them")

    def _placed_overlaps(self) -> None:
        """Registers the address rule places must not share an address with another."""
        placed = self.d._generated()
        owner: dict[int, str] = {}
        for key, reg in self.d.regs.items():
            if reg.space != 0:
                continue
            for a in reg.addresses():
                other = owner.setdefault(a, key)
                if other != key and (key in placed or other in placed):
                    self.out.append(f"cia402.address_rule: {other} and {key} both take "
                                    f"register {a} (the rule must space the objects by the "
                                    f"registers each takes)")
                    return


def _bit_list(mask: int) -> str:
    return ", ".join(str(i) for i in range(32) if mask >> i & 1)


def _width_lo(d: RegisterDef) -> int:
    bits = 16 * d.words
    return -(1 << (bits - 1)) if d.signed else 0


def _width_hi(d: RegisterDef) -> int:
    bits = 16 * d.words
    return (1 << (bits - 1)) - 1 if d.signed else (1 << bits) - 1
