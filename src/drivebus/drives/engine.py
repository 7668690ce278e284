"""The profile class of a description: ``profile_class(description)`` makes it, on the
command engine (``drivebus.drives.command``) or the CiA 402 engine
(``drivebus.drives.cia402_engine``) as ``[drive] engine`` says, with its options'
model, its parameters, its programs and its constructor's signature; the axis layer
above uses it like any hand-written profile. Neither engine imports this factory.
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable
from typing import Annotated, Any, ClassVar, Literal

from pydantic import (
    Field,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    create_model,
    model_validator,
)

from drivebus.bus import SlaveHandle
from drivebus.drives.base import DriveOptions, Parameter, WriteThrough
from drivebus.drives.command.profile import DescribedProfile
from drivebus.drives.command.reads import ReadPlan, _plan, _status_plan, plan_reads
from drivebus.drives.description import Description
from drivebus.drives.registers import Register, WordOrder
from drivebus.drives.values import Attrs

__all__ = ["DescribedProfile", "ReadPlan", "plan_reads", "profile_class"]


def _option_type(o: Any) -> Any:
    bounds: dict[str, Any] = {}
    whole = o.type in ("int", "list")
    if o.min is not None:
        bounds["ge"] = int(o.min) if whole and o.min == int(o.min) else o.min
    if o.max is not None:
        bounds["le"] = int(o.max) if whole and o.max == int(o.max) else o.max
    if o.type == "int":
        return Annotated[StrictInt, Field(**bounds)]
    if o.type == "float":
        return Annotated[StrictFloat | StrictInt, Field(**bounds)]
    if o.type == "bool":
        return StrictBool
    if o.type == "str":
        return StrictStr
    if o.type == "choice":
        return Literal[tuple(o.choices)]
    if o.type == "list":
        return Annotated[list[Annotated[StrictInt, Field(**bounds)]],
                         Field(max_length=o.max_items)]
    return dict[Literal[tuple(o.keys)], Literal[tuple(o.choices)]]  # type: ignore[misc]


class _CheckedOptions(DriveOptions):
    """Options with the description's ``option_checks`` (conditions across options)."""

    description: ClassVar[Description]

    @model_validator(mode="after")
    def _option_checks(self) -> _CheckedOptions:
        d = self.description
        values = {k: (getattr(self, k) if getattr(self, k) is not None else o.default)
                  for k, o in d.options.items()}
        scope = {**d.constants, "option": Attrs("option", values)}
        for oc in d.option_checks:
            if not oc.check(scope):
                raise ValueError(oc.message(scope))
        return self


def options_model(d: Description) -> type[DriveOptions]:
    """The pydantic model of a description's ``drive_options``."""
    fields: dict[str, Any] = {
        k: (_option_type(o) | None, Field(None, description=o.doc))
        for k, o in d.options.items()
    }
    if not d.option_checks:
        return create_model(f"{d.family}Options", __base__=DriveOptions, **fields)
    base = type(f"_{d.family}Checked", (_CheckedOptions,), {"description": d,
                                                           "__module__": __name__})
    return create_model(f"{d.family}Options", __base__=base, **fields)


def profile_class(d: Description) -> type[DescribedProfile]:
    """The ``DriveProfile`` class of description ``d``."""
    link = d.link
    homing = tuple(d.homing.methods) if d.homing is not None else ()
    ident = None
    if d.identify is not None and not d.identify.cannot:
        ident = _plan(d, list(d.identify.read), link.max_read, link.max_hole)
    extras = tuple((x.when, _plan(d, x.read, link.max_read, link.max_hole))
                   for x in d.status.extra)
    attrs: dict[str, Any] = {
        "__doc__": f"{d.drive.description or d.family}: a profile run from its description.",
        "__module__": __name__,
        "description": d,
        "family": d.family,
        "word_order": WordOrder(link.word_order),
        "exception_texts": dict(link.exceptions),
        "homing_methods": homing,
        "options": options_model(d),
        "pulses_per_rev_allowed": d.pulses_per_rev_allowed,
        "addresses": link.address_set,
        "line_kinds": link.line_kinds,
        "baud_rates": tuple(link.baud_rates),
        "line_formats": tuple(link.formats),
        "parameter_read_words": min(DescribedProfile.parameter_read_words, link.max_read),
        "_status_plan": _status_plan(d),
        "_identity_plan": ident,
        "_extra_plans": extras,
        "_coils": frozenset(reg.at(i) for reg in d.regs.values() if reg.d.coil
                            for i in (reg.indices if reg.array else [None])),
    }
    attrs.update(_parameter_attrs(d))
    attrs.update(_program_attrs(d))
    base: type[DescribedProfile] = DescribedProfile
    if d.drive.engine == "cia402":
        from drivebus.drives.cia402_engine import Cia402Profile, cia402_attrs  # on use

        base = Cia402Profile
        attrs.update(cia402_attrs(d))
    name = re.sub(r"\W", "_", d.family) + "Profile"
    cls = type(name, (base,), attrs)
    cls.__init__ = _init_with_signature(d, base)  # type: ignore[method-assign]
    return cls


class Registers:
    """A description's registers as attributes (``profile.regs.microstep.address``)."""

    def __init__(self, d: Description) -> None:
        self._regs = d.regs

    def __getattr__(self, key: str) -> Register:
        if key.startswith("_") or key not in self._regs:
            raise AttributeError(key)
        return self._regs[key].register


def _parameter_attrs(d: Description) -> dict[str, Any]:
    """``parameter_list``/``write_through``/``saves_by_write_through`` of the profile class,
    from the description's registers; ``comms_note`` and, where a register sets the
    address or the line, ``comms_writes`` (``drivebus commission``)."""
    params = []
    for key, reg, index in d.parameter_regs():
        params.append(Parameter(key, reg.at(index), stored=not reg.d.volatile,
                                comms=reg.d.comms, table=tuple(reg.codec.table),
                                meanings={v: n for n, v in reg.codec.values.items()}))
    wt = d.eeprom.write_through
    return {
        "parameter_list": tuple(params),
        "write_through": None if wt is None else WriteThrough(d.regs[wt.reg].register,
                                                               wt.on, wt.off),
        "saves_by_write_through": d.eeprom.saves_by_write_through,
        "comms_note": d.link.comms_note,
        **({"comms_writes": _comms_writes} if any(
            (d.link.address_register, d.link.format_register, d.link.baud_register)) else {}),
    }


def _program_attrs(d: Description) -> dict[str, Any]:
    """``programs``, ``io_inputs``/``io_outputs``, the reasons ``set_output`` and
    ``prepare_table`` give (their procedures' ``unsupported``, or ``set_output``'s doc), the
    table's rows and the registers by key (``regs``) of the profile class."""
    out: dict[str, Any] = {
        "programs": d.programs.support(),
        "io_inputs": tuple(d.inputs.names) if d.inputs is not None else (),
        "io_outputs": tuple(d.outputs.names) if d.outputs is not None else (),
        "regs": Registers(d),
        "table_rows": d.programs.table_rows,
    }
    for attr, proc in (("no_output_control", "set_output"), ("no_table", "prepare_table")):
        p = d.procedures.get(proc)
        if p is not None and p.unsupported is not None:
            out[attr] = p.unsupported
        elif p is not None and p.doc and attr == "no_output_control":
            out[attr] = p.doc  # which outputs it cannot switch, and why
    return out


def _comms_writes(
    self: DescribedProfile, address: int | None, settings: Any, current: Any
) -> list[tuple[Register, int]]:
    """The writes that give the drive ``address`` and line ``settings`` (None: keep): its
    ``[link]`` address, baud and format registers; ``NotSupported`` for what no register
    sets (saying how it is done, ``comms_note``) or what its format rules forbid."""
    link = self.description.link
    regs = self.description.regs
    how = link.comms_note or "the manual documents no register for it"
    writes: list[tuple[Register, int]] = []
    if address is not None:
        if link.address_register is None:
            raise self.unsupported(f"change its address to {address}", how)
        span = link.register_addresses
        if span is not None and not span[0] <= address <= span[1]:
            raise self.unsupported(f"take address {address} from a register",
                                   f"its register gives {span[0]}-{span[1]}; {how}")
        reg = regs[link.address_register].register
        reg.check(address)
        writes.append((reg, address))
    if settings is None:
        return writes
    baud_changes = current is None or settings.baudrate != current.baudrate
    if baud_changes and link.baud_register is not None:
        writes.append(_named_value(self, link.baud_register, str(settings.baudrate),
                                   f"run {settings.baudrate} baud"))
    elif baud_changes and current is not None:
        raise self.unsupported(f"change its baud rate to {settings.baudrate}", how)
    for rule in link.format_rules:
        if settings.baudrate in rule.baud_rates and settings.format not in rule.formats:
            raise self.unsupported(f"talk {settings.format} at {settings.baudrate} baud",
                                   rule.why or f"it talks {'/'.join(rule.formats)} there")
    if link.format_register is not None:
        writes.append(_named_value(self, link.format_register, settings.format,
                                   f"talk {settings.format}"))
    elif link.format_register is None and current is not None and \
            settings.format != current.format:
        raise self.unsupported(f"change its line format to {settings.format}", how)
    return writes


def _named_value(self: DescribedProfile, key: str, name: str, what: str
                 ) -> tuple[Register, int]:
    """(register, value) of register ``key``'s value named ``name`` ('8N2', '38400')."""
    reg = self.description.regs[key]
    if name not in reg.d.values:
        raise self.unsupported(what, f"{reg.register.name} has no value for {name} "
                               f"(it takes {', '.join(reg.d.values)})")
    return reg.register, reg.d.values[name]


def _init_with_signature(d: Description, base: type[DescribedProfile]) -> Callable[..., None]:
    """A constructor whose signature lists the description's options with their defaults
    (what ``inspect`` and the docs show), calling ``DescribedProfile.__init__``."""

    def __init__(self: DescribedProfile, slave: SlaveHandle, **kwargs: Any) -> None:
        base.__init__(self, slave, **kwargs)

    kw = inspect.Parameter.KEYWORD_ONLY
    params = [
        inspect.Parameter("self", inspect.Parameter.POSITIONAL_OR_KEYWORD),
        inspect.Parameter("slave", inspect.Parameter.POSITIONAL_OR_KEYWORD,
                          annotation=SlaveHandle),
        inspect.Parameter("pulses_per_rev", kw, default=d.units.pulses_per_rev.default,
                          annotation=int),
        *(inspect.Parameter(k, kw, default=o.default) for k, o in d.options.items()),
    ]
    __init__.__signature__ = inspect.Signature(params, return_annotation=None)  # type: ignore[attr-defined]
    __init__.__doc__ = f"The {d.family} profile on ``slave``; options as its description says."
    return __init__
