"""The command engine: a ``DriveProfile`` driven by a drive description.

It runs the description's procedures step by step (register and block writes with values
computed from the call, command codes, control-word bits, read-modify-writes, read-backs
and checks, bounded waits, calls of other procedures), polls and decodes the status, and
learns what decoding needs with reads only (``learn``) apart from the writes of ``setup``.
Every procedure is first run dry, without I/O: every value it will write is computed and
range-checked before the first frame, so a bad argument never leaves a command half-sent.

``profile_class(description)`` makes the profile class of a description; the axis layer
above uses it like any hand-written profile.
"""

from __future__ import annotations

import inspect
import math
import re
from collections.abc import Awaitable, Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Annotated, Any, ClassVar, Literal

import anyio
from pydantic import (
    Field,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    create_model,
    model_validator,
)

from drivebus.bus import Priority, SlaveHandle
from drivebus.clock import monotonic
from drivebus.drives.base import (
    DriveOptions,
    DriveProfile,
    HomingParams,
    HomingSwitches,
    MoveParams,
    Parameter,
    WriteThrough,
)
from drivebus.drives.description import PROCEDURES, Description, Procedure, Reg, Step
from drivebus.drives.expr import Expr, ExprError, Unknown
from drivebus.drives.io import IOPoint, function_text
from drivebus.drives.mapping import register_namer
from drivebus.drives.programs import Completion
from drivebus.drives.registers import Register, WordOrder
from drivebus.drives.status import DriveIdentity, DriveStatus
from drivebus.drives.units import Kind
from drivebus.drives.values import (
    Attrs,
    FunctionNames,
    IoSignals,
    RegValue,
    Table,
    Unread,
    reg_value,
)
from drivebus.errors import (
    ConfigError,
    DriveAlarm,
    LimitViolation,
    MotionError,
    NotSupported,
    StateError,
    UnknownMethod,
)

__all__ = ["DescribedProfile", "ReadPlan", "plan_reads", "profile_class"]

_PRIORITY = {"emergency": Priority.EMERGENCY, "command": Priority.COMMAND,
             "config": Priority.CONFIG, "poll": Priority.POLL}
_DEFAULT_PRIORITY = {
    "learn": Priority.CONFIG, "setup": Priority.CONFIG, "save_parameters": Priority.CONFIG,
    "stop": Priority.EMERGENCY, "emergency_stop": Priority.EMERGENCY,
}
INPUT = 1 << 16
"""Where input registers' words sit in a read's words (``INPUT + address``)."""
OBJECT = 1 << 40
"""Where an object-addressed map's words sit in a read's words (``OBJECT + (address << 8)
+ word``): objects at consecutive addresses do not share words."""
_TARGET = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[(.+)\])?")
_MAX_DEPTH = 8


# -- reads ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class ReadPlan:
    """Which registers to read and in which transactions."""

    blocks: tuple[tuple[int, int], ...]
    """(first address, count) per FC03."""
    regs: tuple[tuple[Reg, int | None], ...]
    """(register, table index) read, each decoded from the blocks' words."""
    input_blocks: tuple[tuple[int, int], ...] = ()
    """(first address, count) per FC04, for input registers."""
    coil_blocks: tuple[tuple[int, int], ...] = ()
    """(first address, count) per FC01, for coils."""
    discrete_blocks: tuple[tuple[int, int], ...] = ()
    """(first address, count) per FC02, for discrete inputs."""
    space_order: tuple[int, ...] = (0, 1, 2, 3)
    """The address spaces in the order they are read (a listed poll: as listed)."""
    object_blocks: tuple[tuple[int, int], ...] = ()
    """(object address, count) per FC03 of an object-addressed map: each object read by
    itself, with its address (with the holding registers)."""


Span = tuple[int, int, int]
"""A read given whole: (address space, first address, last address); the spaces as
``Reg.space`` numbers them (0 holding, 1 input registers, 2 coils, 3 discrete inputs)."""


def plan_reads(
    targets: Iterable[tuple[Reg, int | None]], *, max_read: int, max_hole: int,
    spans: Iterable[Span] = (),
) -> ReadPlan:
    """Cover ``targets`` (and the address ``spans`` given whole, each in its own address
    space) with as few reads as ``max_read`` registers per read and gaps of at most
    ``max_hole`` allow."""
    spaces: tuple[set[int], ...] = (set(), set(), set(), set())
    wanted, inputs = spaces[0], spaces[1]
    objects: dict[int, int] = {}
    regs = []
    for reg, index in targets:
        r = reg.at(index) if reg.array else reg.register
        if r.objects:  # its object by itself, through its last word
            objects[r.address] = max(objects.get(r.address, 0), r.offset + r.words)
            regs.append((reg, index))
            continue
        space = spaces[reg.space]
        space.add(r.address)
        if r.words == 2:
            space.add(r.low_address if r.low_address is not None else r.address + 1)
        regs.append((reg, index))
    for space_no, first, last in spans:
        spaces[space_no].update(range(first, last + 1))
    return ReadPlan(_blocks(wanted, max_read, max_hole), tuple(regs),
                    _blocks(inputs, max_read, max_hole), _blocks(spaces[2], max_read, max_hole),
                    _blocks(spaces[3], max_read, max_hole),
                    object_blocks=tuple(sorted(objects.items())))


def _blocks(addresses: set[int], max_read: int, max_hole: int) -> tuple[tuple[int, int], ...]:
    blocks: list[tuple[int, int]] = []
    for a in sorted(addresses):
        if blocks:
            start, count = blocks[-1]
            end = start + count  # next address after the block
            if a - end <= max_hole and a - start + 1 <= max_read:
                blocks[-1] = (start, a - start + 1)
                continue
        blocks.append((a, 1))
    return tuple(blocks)


# -- evaluation contexts -----------------------------------------------------------------


class _Last:
    """``last.REGISTER``: the physical value this profile last wrote (None if never)."""

    __slots__ = ("_values",)

    def __init__(self, values: Mapping[str, Any]) -> None:
        self._values = values

    def __getattr__(self, key: str) -> Any:
        if key.startswith("_"):
            raise AttributeError(key)
        return self._values.get(key)


@dataclass
class _Run:
    """One run of a procedure: its arguments, what it read and wrote, dry or not."""

    proc: str
    args: dict[str, Any]
    dry: bool
    priority: Priority
    depth: int = 0
    values: dict[str, Any] = field(default_factory=dict)
    """Register key -> value (a ``Table`` for tables) read by this run."""
    written: dict[str, Any] = field(default_factory=dict)
    """Register (or ``key[index]``) -> physical value written by this run."""
    result: Any = None
    home: Attrs | None = None
    trace: list[tuple[str, Reg, int | None, int, str]] = field(default_factory=list)
    """(step action, register, index, raw, source expression) of every value written."""


@dataclass
class _Item:
    reg: Reg
    index: int | None
    register: Register
    value: Any
    source: Expr
    nonzero: bool
    as_raw: bool = False
    raw: int = 0
    physical: Any = None

    @property
    def key(self) -> str:
        return self.reg.key if self.index is None else f"{self.reg.key}[{self.index}]"


class DescribedProfile(DriveProfile):
    """A profile that runs a drive description (the command engine)."""

    description: ClassVar[Description]
    _status_plan: ClassVar[ReadPlan]
    _identity_plan: ClassVar[ReadPlan | None]
    _extra_plans: ClassVar[tuple[tuple[Expr, ReadPlan], ...]]
    _coils: ClassVar[frozenset[Register]] = frozenset()
    """The codec registers that are coils (written with FC05)."""

    def __init__(
        self, slave: SlaveHandle, *, pulses_per_rev: int | None = None, **options: Any
    ) -> None:
        d = self.description
        self.check_options(options)
        ppr = d.units.pulses_per_rev.default if pulses_per_rev is None else pulses_per_rev
        super().__init__(slave, pulses_per_rev=ppr)
        values = {k: (o.default if k not in options or options[k] is None else options[k])
                  for k, o in d.options.items()}
        for k, o in d.options.items():  # a map's entries in the order of its keys
            if o.type == "map" and isinstance(values[k], Mapping):
                given = values[k]
                values[k] = {key: given[key] for key in o.keys if key in given}
        self.options_given = dict(values)
        self.option = Attrs("option", values)
        self.state: dict[str, Any] = dict(d.state)
        self.last: dict[str, Any] = {}
        self.learned: dict[str, Any] = {}
        self._learned = False
        self._signal_due: dict[str, float] = {}
        self.signals: dict[str, Any] = {}
        """The latest value of each of the description's signals (``read_signals``)."""
        timeout = d.link.timing.response_timeout
        if timeout is not None and slave.timeout < timeout:
            slave.timeout = timeout
        slave.register_names = register_namer(d)
        timing = d.link.timing
        slave.guard = max(slave.guard, timing.guard)
        slave.frame_timeout = max(slave.frame_timeout, timing.frame_timeout or 0.0)

    # -- declarations the base class and machine files use ---------------------------------

    @classmethod
    def settings_problem(cls, settings: Any) -> str | None:
        """As declared, and the description's format rules at some baud rates."""
        problem = super().settings_problem(settings)
        if problem is not None:
            return problem
        for rule in cls.description.link.format_rules:
            if settings.baudrate in rule.baud_rates and settings.format not in rule.formats:
                why = f" ({rule.why})" if rule.why else ""
                return (f"the {cls.family} drive runs {'/'.join(rule.formats)} only at "
                        f"{settings.baudrate} baud{why}")
        return None

    def check_supported(self, procedure: str) -> None:
        """``NotSupported`` if the description lacks ``procedure`` (or its condition on
        the options does not hold)."""
        self._procedure(procedure, {})

    def _steps_of(self, name: str) -> Procedure | None:
        """The description's procedure ``name`` where it has steps (None: absent, or
        marked unsupported)."""
        proc = self.description.procedures.get(name)
        return proc if proc is not None and proc.unsupported is None else None

    def _procedure(self, name: str, args: Mapping[str, Any]) -> Procedure:
        d = self.description
        proc = d.procedures.get(name)
        what = self._what(name, proc, args)
        if proc is None:
            raise self.unsupported(what)
        if proc.unsupported is not None:
            raise self.unsupported(what, proc.unsupported)
        if proc.supported is not None and not proc.supported(self._scope(None)):
            raise self.unsupported(what, proc.why)
        return proc

    def _what(self, name: str, proc: Procedure | None, args: Mapping[str, Any]) -> str:
        if proc is not None and proc.what is not None:
            try:
                return proc.what({**self._scope(None), **args})
            except (ExprError, Unknown):
                return str(proc.what)
        return self.description.procedure_what(name)

    # -- evaluation -------------------------------------------------------------------------

    def _scope(self, run: _Run | None, values: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The names an expression sees."""
        d = self.description
        unread = self.__dict__.get("_unread")
        if unread is None:  # made once: a scope is built for every step of every command
            unread = self.__dict__["_unread"] = {key: Unread(key) for key in d.regs}
            self.__dict__["_function_names"] = (FunctionNames(d.inputs),
                                                FunctionNames(d.outputs))
        scope = dict(unread)
        scope.update(self.learned)
        if values is not None:
            scope.update(values)
        if run is not None:
            scope.update(run.values)
        scope.update(d.constants)
        scope["option"] = self.option
        scope["state"] = Attrs("state", self.state)
        scope["last"] = _Last(self.last)
        scope["pulses_per_rev"] = self.pulses_per_rev
        scope["input"] = IoSignals(d, "inputs", scope)
        scope["output"] = IoSignals(d, "outputs", scope)
        scope["input_functions"], scope["output_functions"] = self.__dict__["_function_names"]
        if run is not None:
            scope.update(run.args)
            if run.home is not None:
                scope["home"] = run.home
        return scope

    # -- running procedures -----------------------------------------------------------------

    async def run(self, name: str, *args: Any, **kwargs: Any) -> Any:
        """Run procedure ``name`` with its parameters (positional or by name)."""
        d = self.description
        proc = d.procedures.get(name)
        params = list(PROCEDURES[name][1]) if name in PROCEDURES else \
            [p.name for p in (proc.params if proc is not None else [])]
        if len(args) > len(params):
            raise TypeError(f"{name}() takes {len(params)} arguments, got {len(args)}")
        call = dict(zip(params, args, strict=False))
        for k, v in kwargs.items():
            if k not in params:
                raise TypeError(f"{name}() has no parameter {k!r}")
            call[k] = v
        if proc is not None:
            for p in proc.params:
                call.setdefault(p.name, p.default)
        for p in params:
            call.setdefault(p, None)
        return await self._run(name, call)

    async def _run(self, name: str, args: dict[str, Any], *, depth: int = 0,
                   priority: Priority | None = None) -> Any:
        if depth > _MAX_DEPTH:
            raise ConfigError(f"{self.family}: procedure {name} calls itself too deep")
        proc = self._procedure(name, args)
        prio = priority or self._priority(name, proc)
        home = self._home_attrs(args) if name == "home" else None
        dry = _Run(name, dict(args), True, prio, depth, home=home)
        self._dry(proc, dry)
        run = _Run(name, dict(args), False, prio, depth, home=home)
        try:
            await self._steps(proc.steps, run)
        except Unknown as exc:
            raise ConfigError(f"{self.family}: procedure {name} uses what it has not read "
                              f"({exc}): read it in a step before") from None
        if name == "learn":  # called from setup at the point the drive needs it
            self.learned.update(run.values)
            self._learned = True
        return run.result

    def _priority(self, name: str, proc: Procedure) -> Priority:
        if proc.priority is not None:
            return _PRIORITY[proc.priority]
        return _DEFAULT_PRIORITY.get(name, Priority.COMMAND)

    def _dry(self, proc: Procedure, run: _Run) -> None:
        """Evaluate ``proc`` without I/O: every value it writes is range-checked now, up to
        the first step that needs what the drive answers."""
        for step in proc.steps:
            try:
                if step.when is not None and not step.when(self._scope(run)):
                    continue
            except Unknown:  # depends on the drive's answers: it may run, check it
                if step.action == "fail":
                    continue
                unknown_when = True
            else:
                unknown_when = False
            try:
                if step.action == "write":
                    self._items(step, run)
                elif step.action == "call":
                    assert step.call is not None
                    sub = self._procedure(step.call, {})
                    args = self._args(step, run)
                    self._dry(sub, _Run(step.call, args, True, run.priority, run.depth + 1))
                elif step.action == "fail":
                    break  # raised for real by the run
                elif step.action == "check" and step.error == "limit":
                    assert step.check is not None
                    if not step.check(self._scope(run)):  # Unknown: not known before I/O
                        self._fail_check(step, run)
            except Unknown:
                continue  # a value only the drive's answers give: checked when it runs
            # reads, waits, checks and sets go on: later writes that need no answer of
            # the drive's are range-checked before the first frame too
            if (step.end or step.action == "return") and not unknown_when:
                break

    def _args(self, step: Step, run: _Run) -> dict[str, Any]:
        scope = self._scope(run)
        args = {k: e(scope) for k, e in step.args.items()}
        assert step.call is not None
        for p in PROCEDURES.get(step.call, ("", ()))[1]:
            args.setdefault(p, None)
        return args

    async def _steps(self, steps: Sequence[Step], run: _Run, *,
                     stop_at_start: bool = False, from_start: bool = False) -> None:
        started = False
        for step in steps:
            if step.start:
                started = True
                if stop_at_start:
                    return
            if from_start and not started:
                continue
            if step.when is not None and not step.when(self._scope(run)):
                continue
            await self._step(step, run)
            if step.end or step.action == "return":
                return

    async def _step(self, step: Step, run: _Run) -> None:
        prio = _PRIORITY[step.priority] if step.priority else run.priority
        action = step.action
        if action == "write":
            await self._write(step, run, prio)
        elif action == "read":
            assert step.read is not None
            run.values.update(await self._read_items(step.read, run, prio))
        elif action == "modify":
            await self._modify(step, run, prio)
        elif action == "call":
            assert step.call is not None
            await self._run(step.call, self._args(step, run), depth=run.depth + 1,
                            priority=_PRIORITY[step.priority] if step.priority else None)
        elif action == "check":
            assert step.check is not None
            if not step.check(self._scope(run)):
                self._fail_check(step, run)
        elif action == "wait":
            await self._wait(step, run, prio)
        elif action == "set":
            assert step.set is not None
            scope = self._scope(run)
            updates = {k: e(scope) for k, e in step.set.items()}
            self.state.update(updates)
        elif action == "fail":
            assert step.fail is not None
            raise self.unsupported(self._what(run.proc, self.description.procedures.get(
                run.proc), run.args),
                                   step.fail(self._scope(run)))
        elif action == "return":
            assert step.return_ is not None
            run.result = step.return_(self._scope(run))

    def _fail_check(self, step: Step, run: _Run, default: str | None = None) -> None:
        """Raise the error ``step`` says (``error``), with its ``message`` or ``default``."""
        scope = self._scope(run)
        text = step.message(scope) if step.message is not None else \
            default or f"check {step.check} failed after {run.proc}"
        msg = f"{self.family}: {text}"
        if step.error == "alarm":
            code, alarm_text = self._alarm_of(scope)
            raise DriveAlarm(msg, code=code, text=alarm_text)
        if step.error == "motion":
            raise MotionError(msg)
        if step.error == "limit":
            raise LimitViolation(text)
        raise StateError(msg)

    def _alarm_of(self, scope: Mapping[str, Any]) -> tuple[int | None, str]:
        alarms = self.description.alarms
        if alarms is None:
            return None, ""
        v = scope.get(alarms.reg)
        if v is None or isinstance(v, Unread):
            return None, ""
        return int(v), self.alarm_text(int(v))

    # -- writes ---------------------------------------------------------------------------

    def _target(self, key: str, scope: Mapping[str, Any]) -> tuple[Reg, int | None]:
        m = _TARGET.fullmatch(key.strip())
        assert m is not None  # checked when the description was loaded
        reg = self.description.regs[m.group(1)]
        index = None
        if m.group(2) is not None:
            index = Expr.parse(m.group(2))(scope)
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

    async def _wait(self, step: Step, run: _Run, prio: Priority) -> None:
        assert step.wait is not None
        timeout = float(step.timeout(self._scope(run)))
        targets = step.read
        try:
            with anyio.fail_after(timeout):
                while True:
                    if targets:
                        run.values.update(await self._read_items(targets, run, prio))
                    else:
                        run.values.update(await self._poll_values(self._status_plan, prio))
                    if step.wait(self._scope(run)):
                        return
                    await anyio.sleep(step.every)  # poll period; the read is the condition
        except TimeoutError:  # a typed error naming the condition, not a bare timeout
            self._fail_check(step, run, f"{run.proc}: {step.wait.source!r} did not hold "
                                        f"within {timeout:g} s")

    # -- reads -----------------------------------------------------------------------------

    def _read_targets(self, items: Sequence[str | list[str]],
                      scope: Mapping[str, Any]) -> tuple[list[tuple[Reg, int | None]],
                                                         list[Span]]:
        regs = self.description.regs
        targets: list[tuple[Reg, int | None]] = []
        spans: list[Span] = []
        for item in items:
            if isinstance(item, list):
                first_reg, first_i = self._target(item[0], scope)
                last_reg, last_i = self._target(item[1], scope)
                last = last_reg.at(last_i)
                span = (first_reg.space, first_reg.at(first_i).address,
                        last.low_address if last.low_address is not None else
                        last.address + last.words - 1)
                spans.append(span)
                targets.extend(_in_span(regs.values(), span))
            elif "[" in item:
                targets.append(self._target(item, scope))
            else:
                reg = regs[item]
                targets.extend((reg, i) for i in (reg.indices if reg.array else [None]))
        return targets, spans

    async def _read_items(self, items: Sequence[str | list[str]], run: _Run | None,
                          prio: Priority) -> dict[str, Any]:
        targets, spans = self._read_targets(items, self._scope(run))
        link = self.description.link
        plan = plan_reads(targets, max_read=link.max_read, max_hole=link.max_hole, spans=spans)
        return await self._poll_values(plan, prio)

    async def _read_words(self, plan: ReadPlan, prio: Priority) -> dict[int, int]:
        """The words of ``plan``: holding registers by address, input registers by
        ``INPUT + address``."""
        words: dict[int, int] = {}
        reads = {0: (plan.blocks, self.slave.read_holding_registers),
                 1: (plan.input_blocks, self.slave.read_input_registers),
                 2: (plan.coil_blocks, self.slave.read_coils),
                 3: (plan.discrete_blocks, self.slave.read_discrete_inputs)}
        for space in plan.space_order:
            blocks, read = reads[space]
            for start, count in blocks:
                got = await read(start, count, priority=prio)
                base = (space << 16) + start  # INPUT for input registers
                words.update(zip(range(base, base + count), got, strict=True))
            if space == 0:
                for address, count in plan.object_blocks:
                    got = await self.slave.read_holding_registers(address, count,
                                                                  priority=prio)
                    base = OBJECT + (address << 8)
                    words.update(zip(range(base, base + count), got, strict=True))
        return words

    async def _poll_values(self, plan: ReadPlan, prio: Priority,
                           raw_words: dict[str, list[int]] | None = None) -> dict[str, Any]:
        words = await self._read_words(plan, prio)
        return self._decode(plan, words, raw_words)

    def _decode(self, plan: ReadPlan, words: Mapping[int, int],
                raw_words: dict[str, list[int]] | None = None) -> dict[str, Any]:
        """Register key -> value for every register of ``plan`` (ramp times after the
        speeds they refer to)."""
        out: dict[str, Any] = {}
        tables: dict[str, dict[int, Any]] = {}
        pending = []
        for reg, index in plan.regs:
            if reg.codec.kind is Kind.RAMP:
                pending.append((reg, index))
                continue
            self._decode_one(reg, index, words, out, tables, raw_words)
        for reg, index in pending:
            self._decode_one(reg, index, words, out, tables, raw_words)
        for key, entries in tables.items():
            out[key] = Table(self.description.regs[key], entries)
        return out

    def _decode_one(self, reg: Reg, index: int | None, words: Mapping[int, int],
                    out: dict[str, Any], tables: dict[str, dict[int, Any]],
                    raw_words: dict[str, list[int]] | None) -> None:
        r = reg.at(index)
        base = reg.space << 16  # input registers, coils, discrete inputs: spaces apart
        if r.objects:
            at = OBJECT + (r.address << 8) + r.offset
            ws = [words[at + j] for j in range(r.words)]
        elif r.words == 2:
            low = r.low_address if r.low_address is not None else r.address + 1
            ws = [words[base + r.address], words[base + low]]
        else:
            ws = [words[base + r.address]]
        raw = r.decode(ws)
        ref = None
        if reg.codec.kind is Kind.RAMP and isinstance(reg.codec.ramp, str):
            ref_val = out.get(reg.codec.ramp, self.last.get(reg.codec.ramp))
            ref = None if ref_val is None or isinstance(ref_val, Table) else float(ref_val)
        physical = reg.codec.to_physical(raw, ppr=self.pulses_per_rev, ref_rpm=ref)
        value = reg_value(reg, raw, physical)
        if index is not None and reg.array:
            tables.setdefault(reg.key, {})[index] = value
        else:
            out[reg.key] = value
            if raw_words is not None:
                raw_words[reg.key] = ws

    # -- learn and setup -------------------------------------------------------------------

    async def learn(self) -> None:
        """Read what decoding needs (the description's ``learn`` reads); never writes."""
        proc = self._steps_of("learn")
        if proc is not None:
            run = _Run("learn", {}, False, Priority.CONFIG)
            await self._steps(proc.steps, run)
            self.learned.update(run.values)
        self._learned = True

    async def setup(self) -> None:
        """The description's ``setup`` writes (before the first command), then ``learn``."""
        self._learned = False
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

    # -- status ------------------------------------------------------------------------------

    async def read_status(self, *, priority: Priority = Priority.POLL) -> DriveStatus:
        """The status poll, decoded as the description says."""
        if not self._learned and self.description.status.learn_first:
            await self.learn()
        raw_words: dict[str, list[int]] = {}
        requested = monotonic()
        values = await self._poll_values(self._status_plan, priority, raw_words)
        try:
            for when, plan in self._extra_plans:
                if when(self._scope(None, values)):
                    values.update(await self._poll_values(plan, priority, raw_words))
            await self._read_due_signals(priority)
            return self.decode_status(values, raw_words, requested_at=requested)
        except Unknown as exc:
            raise ConfigError(f"{self.family}: its status decoding uses what the poll does "
                              f"not read ({exc}): add it to [status] poll") from None

    def fresh(self, requested_at: float | None) -> bool:
        """True if a status requested at ``requested_at`` (None: not known) left after
        the reply to the last write: only such a status may change what the profile
        tracks of a command (a homing under way, a motion started)."""
        slave = self.__dict__.get("slave")
        return requested_at is None or slave is None or requested_at > slave.wrote_at

    def decode_status(self, values: Mapping[str, Any],
                      raw_words: Mapping[str, list[int]] | None = None, *,
                      requested_at: float | None = None) -> DriveStatus:
        """A ``DriveStatus`` from the polled register values. Its state trackers take
        only a status requested after the last write's reply (``fresh``)."""
        d = self.description
        s = d.status
        fields = d.status_exprs
        scope = self._scope(None, values)
        scope["words"] = Attrs("words", dict(raw_words or {}))
        if s.track and self.fresh(requested_at):  # trackers first: the fields see them
            updates = {k: e(scope) for k, e in s.track.items()}
            self.state.update(updates)
            scope = self._scope(None, values)
            scope["words"] = Attrs("words", dict(raw_words or {}))

        def flag(name: str) -> bool:
            e = fields.get(name)
            return bool(e(scope)) if e is not None else False

        alarm = flag("alarm")
        code = None
        text = ""
        if alarm and "alarm_code" in fields:
            code = int(fields["alarm_code"](scope))
            text = self.alarm_text(code) if code else ""
        position = _physical(fields["position"], scope, d, "position") \
            if "position" in fields else None
        velocity = _physical(fields["velocity"], scope, d, "velocity") \
            if "velocity" in fields else None
        raw = _raw_values(s.raw, scope) if s.raw else {
            k: int(v) for k, v in values.items() if isinstance(v, int)}
        return DriveStatus(
            enabled=flag("enabled"),
            moving=flag("moving"),
            in_position=flag("in_position"),
            homed=flag("homed"),
            alarm=alarm,
            alarm_code=code,
            alarm_text=text,
            limit_positive=flag("limit_positive"),
            limit_negative=flag("limit_negative"),
            homing=flag("homing"),
            homing_error=flag("homing_error"),
            position=None if position is None else int(position),
            velocity_rpm=None if velocity is None else float(velocity),
            raw=raw,
            timestamp=monotonic(),
            requested_at=requested_at or 0.0,
        )

    def alarm_text(self, code: int) -> str:
        """The description's text for alarm code ``code`` (flags: each bit's text)."""
        a = self.description.alarms
        if a is None:
            return f"alarm code {code}"
        if code in a.texts:
            return a.texts[code]
        if a.kind == "flags":
            parts = [t for bit, t in a.texts.items() if code & bit]
            unknown = code & ~sum(a.texts)
            if unknown:
                parts.append(a.unknown({"code": code, "bits": unknown}))
            return "; ".join(parts)
        return a.unknown({"code": code, "bits": code})

    async def read_signals(self, names: Iterable[str] | None = None, *,
                           priority: Priority = Priority.POLL) -> dict[str, Any]:
        """Read the description's signals (all, or ``names``) now."""
        d = self.description
        wanted = list(d.signals) if names is None else list(names)
        for n in wanted:
            if n not in d.signals:
                raise ConfigError(f"{self.family} has no signal {n!r} (it has "
                                  f"{', '.join(d.signals) or 'none'})")
        items = [d.signals[n].reg for n in wanted]
        values = await self._read_items(items, None, priority) if items else {}
        for n in wanted:
            self.signals[n] = values.get(d.signals[n].reg)
            self._signal_due[n] = monotonic() + d.signals[n].every
        return {n: self.signals[n] for n in wanted}

    async def _read_due_signals(self, priority: Priority) -> None:
        d = self.description
        if not d.signals:
            return
        now = monotonic()
        due = [n for n in d.signals if self._signal_due.get(n, 0.0) <= now]
        if due:
            await self.read_signals(due, priority=priority)

    # -- identity -----------------------------------------------------------------------------

    def is_own_identity(self, ident: DriveIdentity) -> bool:
        """The description's ``identify.match`` on what ``read_identity`` read."""
        ident_d = self.description.identify
        if ident_d is None or ident_d.match is None or not ident.raw:
            return False
        values = getattr(ident, "_values", None)
        scope = self._scope(None, values if values is not None else ident.raw)
        try:
            return bool(ident_d.match(scope))
        except (ExprError, Unknown):
            return False

    async def read_identity(self) -> DriveIdentity:
        """The registers of ``identify.read``, with the model and firmware texts."""
        ident_d = self.description.identify
        if ident_d is None or ident_d.cannot:
            return DriveIdentity(self.family)
        values = await self._read_items(list(ident_d.read), None, Priority.CONFIG)
        scope = self._scope(None, values)
        raw = {k: int(e(scope)) for k, e in ident_d.raw.items()} if ident_d.raw else {
            k: int(v) for k, v in values.items() if isinstance(v, int)}
        return DriveIdentity(self.family, model=ident_d.model(scope),
                             firmware=ident_d.firmware(scope), raw=raw)

    # -- procedures -----------------------------------------------------------------------

    async def enable(self) -> None:
        """The description's ``enable``."""
        await self.run("enable")

    async def disable(self) -> None:
        """The description's ``disable``."""
        await self.run("disable")

    def _move_args(self, target: int | None, params: MoveParams, name: str) -> dict[str, Any]:
        key = "distance" if name == "move_relative" else "target"
        return {key: target, "speed": params.speed_rpm, "accel": params.accel_rps2,
                "decel": params.decel_rps2}

    def _dry_trace(self, name: str, args: dict[str, Any]) -> list[tuple[str, Reg, int | None,
                                                                         int, str]]:
        proc = self._procedure(name, args)
        run = _Run(name, args, True, Priority.COMMAND)
        self._dry(proc, run)
        return run.trace

    def check_move(self, params: MoveParams) -> None:
        """Range-check what a move with ``params`` would write (no I/O)."""
        self._dry_trace("move_absolute", self._move_args(0, params, "move_absolute"))

    def quantize(self, params: MoveParams) -> MoveParams:
        """The speed and ramps the drive runs after its registers' rounding.

        A planner asks this hundreds of times per move: the registers that take the speed
        and ramps are found once (a dry run of ``move_absolute``), then each call only
        rounds through their codecs; a description whose move writes them otherwise than
        as given is quantized by a dry run each time."""
        recipe = self.__dict__.get("_quantize_recipe", ())
        if recipe == ():  # not found yet: from these values, if the drive takes them
            recipe = self._find_quantize_recipe(params)
            if recipe == ():
                return self._quantize_by_dry_run(params)
            self.__dict__["_quantize_recipe"] = recipe
        if recipe is None:
            return self._quantize_by_dry_run(params)
        return self._quantize_by(recipe, params)

    def _quantize_by(self, recipe: Sequence[tuple[str, Reg, Register]],
                     params: MoveParams) -> MoveParams:
        """``params`` rounded through the registers of ``recipe`` (speeds before ramps)."""
        given = {"speed": abs(params.speed_rpm), "accel": params.accel_rps2,
                 "decel": params.decel_rps2}
        out = dict(given)
        ppr = self.pulses_per_rev
        try:
            for name, reg, register in recipe:
                codec = reg.codec
                ref = out["speed"] if codec.kind is Kind.RAMP else None
                raw = codec.to_raw(register, given[name], ppr=ppr, ref_rpm=ref)
                v = codec.to_physical(raw, ppr=ppr, ref_rpm=ref)
                if isinstance(v, int | float) and math.isfinite(v):
                    out[name] = abs(float(v))
        except (LimitViolation, NotSupported):
            return params
        return MoveParams(out["speed"], out["accel"], out["decel"])

    def _find_quantize_recipe(
        self, params: MoveParams
    ) -> tuple[tuple[str, Reg, Register], ...] | tuple[()] | None:
        """The registers ``move_absolute`` writes the speed and ramps to, as given (not
        through an expression), speeds first; None if they cannot be found that way, or
        if rounding through them disagrees with a dry run on values near ``params``;
        ``()`` if the drive does not take ``params`` (ask again with others)."""
        recipe: list[tuple[str, Reg, Register]] = []
        try:
            trace = self._dry_trace("move_absolute",
                                    self._move_args(0, params, "move_absolute"))
        except LimitViolation:
            return ()
        except (NotSupported, ConfigError, Unknown):
            return None
        for _, reg, index, _raw, source in trace:
            text = source.replace(" ", "")
            name = text.removeprefix("abs(").removesuffix(")")
            if reg.codec.kind not in (Kind.SPEED, Kind.ACCEL, Kind.RAMP):
                continue
            if name in ("speed", "accel", "decel") and text in (name, f"abs({name})"):
                recipe.append((name, reg, reg.at(index)))
            elif re.search(r"\b(speed|accel|decel)\b", text):
                return None  # written through an expression: only a dry run knows
            continue  # another value (a start speed from an option): not the move's
        recipe.sort(key=lambda r: r[1].codec.kind is Kind.RAMP)
        for f in (1.0, 0.93, 1.07, 0.71):
            sample = MoveParams(params.speed_rpm * f, params.accel_rps2 / f,
                                params.decel_rps2 * f)
            if self._quantize_by(recipe, sample) != self._quantize_by_dry_run(sample):
                return None
        return tuple(recipe)

    def _quantize_by_dry_run(self, params: MoveParams) -> MoveParams:
        """``quantize`` by running ``move_absolute`` dry and reading back what it wrote."""
        try:
            trace = self._dry_trace("move_absolute", self._move_args(0, params, "move_absolute"))
        except (LimitViolation, NotSupported):
            return params
        speed = abs(params.speed_rpm)
        out = {"speed": speed, "accel": params.accel_rps2, "decel": params.decel_rps2}
        written: dict[str, float] = {}
        # Speeds first: a ramp time was encoded against the speed as written (rounded).
        for _, reg, _index, raw, source in sorted(
                trace, key=lambda t: t[1].codec.kind is Kind.RAMP):
            name = source.replace("abs(", "").rstrip(")").strip()
            if name not in out or reg.codec.kind not in (Kind.SPEED, Kind.ACCEL, Kind.RAMP):
                continue
            ref = None
            if reg.codec.kind is Kind.RAMP:
                ref = written.get("speed", speed)
            v = reg.codec.to_physical(raw, ppr=self.pulses_per_rev, ref_rpm=ref)
            if isinstance(v, int | float) and math.isfinite(v):
                written[name] = abs(float(v))
        for name, v in written.items():
            out[name] = v
        return MoveParams(out["speed"], out["accel"], out["decel"])

    async def move_absolute(self, position: int, params: MoveParams) -> None:
        """The description's ``move_absolute``."""
        await self.run("move_absolute", **self._move_args(position, params, "move_absolute"))

    async def prepare_absolute(self, position: int, params: MoveParams) -> None:
        """``move_absolute`` up to its step marked ``start``."""
        args = self._move_args(position, params, "move_absolute")
        proc = self._procedure("move_absolute", args)
        if not any(s.start for s in proc.steps):
            await super().prepare_absolute(position, params)
            return
        self._dry(proc, _Run("move_absolute", dict(args), True, Priority.COMMAND))
        run = _Run("move_absolute", dict(args), False, Priority.COMMAND)
        await self._steps(proc.steps, run, stop_at_start=True)
        self._prepared_run = run

    async def start_absolute(self) -> None:
        """The rest of the prepared ``move_absolute``, from its step marked ``start``."""
        run = getattr(self, "_prepared_run", None)
        if run is None:
            await super().start_absolute()
            return
        proc = self._procedure("move_absolute", run.args)
        await self._steps(proc.steps, run, from_start=True)

    async def move_relative(self, distance: int, params: MoveParams) -> None:
        """The description's ``move_relative``."""
        await self.run("move_relative", **self._move_args(distance, params, "move_relative"))

    async def speed_run(self, speed_rpm: float, accel_rps2: float, decel_rps2: float) -> None:
        """The description's ``speed_run`` (signed speed)."""
        await self.run("speed_run", speed=speed_rpm, accel=accel_rps2, decel=decel_rps2)

    def stop_takes_decel(self) -> bool:
        """Whether the description's stop honours a deceleration: its ``takes``, else
        whether its steps use ``decel`` (or pass it to a procedure they call)."""
        proc = self._steps_of("stop")
        return proc is not None and proc.honours("decel")

    async def stop(self, decel_rps2: float | None = None) -> None:
        """The description's ``stop`` (a deceleration it cannot honour is refused first)."""
        self.check_stop(decel_rps2)
        await self.run("stop", decel=decel_rps2)

    async def emergency_stop(self) -> None:
        """The description's ``emergency_stop``."""
        await self.run("emergency_stop")

    def homing_mode(self, method: str | None) -> int | None:
        """The code of homing method ``method`` (a name, or its code as digits)."""
        return self._home_method(method)[1].code

    def _home_method(self, method: str | None) -> tuple[str, Any]:
        h = self.description.homing
        if h is None:
            raise self.unsupported("home")
        name = next(iter(h.methods)) if method is None else method
        if name in h.methods:
            return name, h.methods[name]
        if isinstance(name, str) and name.isdigit():
            for n, m in h.methods.items():
                if m.code == int(name):
                    return n, m
        documented = ", ".join(f"{n} ({m.code})" if m.code is not None else n
                               for n, m in h.methods.items())
        raise UnknownMethod(str(self.unsupported(
            f"home with method {method!r}",
            f"it has no homing method {method!r}; it documents {documented}")))

    def homing_switches(self, method: str | None) -> HomingSwitches:
        """The limit switches homing with ``method`` homes on or reverses at: the method's
        ``homes_on``/``reverses_at`` (+1/-1) where it gives them, else its CiA 402
        method's (17/18 home on a limit switch; 23-30 reverse at the one ahead)."""
        _, m = self._home_method(method)
        extras = m.extras
        if "homes_on" in extras or "reverses_at" in extras:
            scope = self._scope(None)
            sides = {k: Expr.parse(v)(scope) if isinstance(v, str) else v  # on the options
                     for k, v in extras.items() if k in ("homes_on", "reverses_at")}
            return HomingSwitches(frozenset(sides.get("homes_on", ())),
                                  frozenset(sides.get("reverses_at", ())))
        return cia402_homing_switches(m.cia402)

    def _home_attrs(self, args: Mapping[str, Any]) -> Attrs:
        name, m = self._home_method(args.get("method"))
        return Attrs("home", {"name": name, "method": name, "code": m.code,
                              "cia402": m.cia402, **m.extras})

    def _homing_args(self, params: HomingParams) -> dict[str, Any]:
        return {"method": params.method, "speed": params.speed_rpm,
                "creep": params.creep_rpm, "accel": params.accel_rps2,
                "offset": params.offset}

    async def start_homing(self, params: HomingParams) -> None:
        """The description's ``home`` with the method's code and extras as ``home.*``."""
        await self.run("home", **self._homing_args(params))

    def check_homing(self, params: HomingParams) -> None:
        """The method known, and what ``home`` writes within range (a dry run)."""
        proc_d = self.description.procedures.get("home")
        args = {**{p.name: p.default for p in (proc_d.params if proc_d else [])},
                **self._homing_args(params)}
        proc = self._procedure("home", args)
        self._dry(proc, _Run("home", args, True, self._priority("home", proc),
                             home=self._home_attrs(args)))

    async def clear_alarm(self) -> None:
        """The description's ``clear_alarm``."""
        await self.run("clear_alarm")

    async def zero_position(self) -> None:
        """The description's ``zero_position``."""
        await self.run("zero_position")

    async def save_parameters(self) -> None:
        """The description's ``save_parameters``."""
        await self.run("save_parameters")

    # -- motion programs and digital I/O ------------------------------------------------------

    async def retarget_absolute(self, position: int, params: MoveParams) -> None:
        """The description's ``retarget_absolute`` (``[programs] retarget`` says how the
        drive takes it); without one, ``NotSupported`` with ``[programs] no_retarget``."""
        if "retarget_absolute" not in self.description.procedures:
            await super().retarget_absolute(position, params)
            return
        await self.run("retarget_absolute",
                       **self._move_args(position, params, "retarget_absolute"))

    async def read_completion(self, *, priority: Priority = Priority.COMMAND) -> Completion | None:
        """``[status.completion]``: its short read, decoded by its expressions (``[status]``'s
        own where it gives none; an alarm or limit field the read cannot decode is False:
        the status polls judge it); None without one (the status poll is used)."""
        c = self.description.status.completion
        if c is None:
            return None
        values = await self._read_items(c.read, None, priority)
        scope = self._scope(None, values)
        fields = self.description.status_exprs

        def flag(name: str) -> bool:
            given = getattr(c, name)
            e = given or fields.get(name)
            try:
                return bool(e(scope)) if e is not None else False
            except Unknown as exc:
                if given is None and name not in ("moving", "in_position"):
                    return False  # an alarm or limit the short read cannot see: polls judge it
                where = f"status.completion.{name}" if given is not None else f"status.{name}"
                raise ConfigError(f"{self.family}: status.completion.read does not read what "
                                  f"{where} uses ({exc})") from None

        return Completion(moving=flag("moving"), in_position=flag("in_position"),
                          alarm=flag("alarm"), limit_positive=flag("limit_positive"),
                          limit_negative=flag("limit_negative"))

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

    async def preflight(self, name: str, **args: Any) -> None:
        """Run procedure ``name``'s steps up to its first step that writes or waits
        (reads, checks and fails only): a refusal it can decide from reads comes before
        anything is written."""
        proc = self._procedure(name, args)
        run = _Run(name, dict(args), False, self._priority(name, proc))
        for step in proc.steps:
            if step.action not in ("read", "check", "fail"):
                return
            if step.when is not None and not step.when(self._scope(run)):
                continue
            await self._step(step, run)

    def __getattr__(self, name: str) -> Callable[..., Awaitable[Any]]:
        """The description's own procedures as methods (``profile.write_position_path(...)``)."""
        if name.startswith("_"):
            raise AttributeError(name)
        d = type(self).__dict__.get("description") or getattr(type(self), "description", None)
        if d is None or name not in d.procedures or name in PROCEDURES:
            raise AttributeError(f"{type(self).__name__!r} has no attribute {name!r}")

        async def call(*args: Any, **kwargs: Any) -> Any:
            return await self.run(name, *args, **kwargs)

        call.__name__ = name
        call.__doc__ = d.procedures[name].doc or f"The {d.family} procedure {name}."
        return call


def cia402_homing_switches(method: int | None) -> HomingSwitches:
    """The limit switches CiA 402 homing method ``method`` homes on or reverses at."""
    if method in (1, 17):
        return HomingSwitches(homes_on=frozenset({-1}))
    if method in (2, 18):
        return HomingSwitches(homes_on=frozenset({1}))
    if method in (7, 8, 9, 10, 23, 24, 25, 26):
        return HomingSwitches(reverses_at=frozenset({1}))
    if method in (11, 12, 13, 14, 27, 28, 29, 30):
        return HomingSwitches(reverses_at=frozenset({-1}))
    return HomingSwitches()


def _raw_values(raw: Mapping[str, Expr], scope: Mapping[str, Any]) -> dict[str, int]:
    """``[status] raw``'s values; one whose register this read did not cover is left out."""
    out: dict[str, int] = {}
    for k, e in raw.items():
        try:
            v = e(scope)
        except Unknown:
            continue
        if v is not None:
            out[k] = int(v)
    return out


def _consecutive(items: Sequence[_Item]) -> list[list[_Item]]:
    """Items grouped into runs of registers that follow on (one FC16 each)."""
    groups: list[list[_Item]] = []
    for it in items:
        if groups and it.register.follows(groups[-1][-1].register):
            groups[-1].append(it)
            continue
        groups.append([it])
    return groups


def _physical(e: Expr, scope: Mapping[str, Any], d: Description, what: str) -> Any:
    """A status field's value: a register's physical value, or the expression's."""
    v = e(scope)
    if isinstance(v, Unread):
        raise Unknown(f"status.{what}: register {v.key} was not polled")
    return v


# -- the profile class of a description ----------------------------------------------------


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


def _ppr_allowed(d: Description) -> Any:
    p = d.units.pulses_per_rev
    if p.allowed:
        return tuple(sorted(p.allowed))
    if p.range is not None:
        return range(p.range[0], p.range[1] + 1)
    if p.reg is not None:
        reg = d.regs[p.reg]
        if reg.codec.table:
            return tuple(sorted(reg.codec.table))
        return scaled_range(max(reg.register.lo, 1), reg.register.hi, reg.codec.scale)
    return range(1, 1 << 31)


def scaled_range(lo: int, hi: int, scale: float) -> Any:
    """The whole values ``raw × scale`` for raw in ``lo..hi``: what a register of that
    range and scale can be set to, in the user's units (pulses/rev through EG/2)."""
    if scale == 1.0:
        return range(lo, hi + 1)
    if scale == int(scale):
        s = int(scale)
        return range(lo * s, hi * s + 1, s)
    inverse = 1.0 / scale
    if abs(inverse - round(inverse)) < 1e-9:
        n = round(inverse)
        return range(-(-lo // n), hi // n + 1)
    return tuple(sorted({round(raw * scale) for raw in range(lo, hi + 1)
                         if abs(raw * scale - round(raw * scale)) < 1e-9}))


def _status_plan(d: Description) -> ReadPlan:
    s = d.status
    link = d.link
    if s.poll:  # read in the order listed
        return _plan(d, list(s.poll), link.max_read, link.max_hole, listed=True)
    names: set[str] = set()
    for e in (*d.status_exprs.values(), *s.raw.values(), *s.track.values()):
        names |= e.names
    for io in (d.inputs,):
        if io is not None and {"input"} & names:
            names.add(io.state)
            if io.invert is not None:
                names.add(io.invert)
    learned = _learned_keys(d)
    items: list[str | list[str]] = sorted(n for n in names if n in d.regs and n not in learned)
    return _plan(d, items, link.max_read, link.max_hole)


def _learned_keys(d: Description) -> set[str]:
    proc = d.procedures.get("learn")
    out: set[str] = set()
    if proc is None:
        return out
    for step in proc.steps:
        for item in step.read or []:
            if isinstance(item, str):
                out.add(item.split("[", 1)[0])
    return out


def _plan(d: Description, items: Sequence[str | list[str]], max_read: int,
          max_hole: int, listed: bool = False) -> ReadPlan:
    targets: list[tuple[Reg, int | None]] = []
    spans: list[Span] = []
    regs = d.regs
    for item in items:
        if isinstance(item, list):
            first = _static_target(d, item[0])
            last = _static_target(d, item[1])
            span = (regs[_item_key(item)].space, first.address,
                    last.low_address if last.low_address is not None else
                    last.address + last.words - 1)
            spans.append(span)
            targets.extend(_in_span(regs.values(), span))
        else:
            reg = regs[item.split("[", 1)[0]]
            targets.extend((reg, i) for i in (reg.indices if reg.array else [None]))
    plan = plan_reads(targets, max_read=max_read, max_hole=max_hole, spans=spans)
    return _in_listed_order(plan, [(d.regs[_item_key(i)], i) for i in items]) if listed \
        else plan


def _in_span(regs: Iterable[Reg], span: Span) -> Iterator[tuple[Reg, int | None]]:
    """The registers (and table entries) of ``span``'s address space within its
    addresses: a span of discrete inputs reads no holding register of the same numbers."""
    space, first, last = span
    for reg in regs:
        if reg.space != space:
            continue
        for index in (reg.indices if reg.array else [None]):
            if first <= reg.at(index).address <= last:
                yield reg, index


def _item_key(item: str | list[str]) -> str:
    return (item[0] if isinstance(item, list) else item).split("[", 1)[0].strip()


def _in_listed_order(plan: ReadPlan, listed: Sequence[tuple[Reg, str | list[str]]]
                     ) -> ReadPlan:
    """``plan`` with its reads of each kind, and the kinds (FC03, FC04, FC01, FC02), in the
    order their registers are listed (a drive whose status takes several reads: the poll
    reads its motion state before the position, so a position read after the drive has
    come to rest is its final one, its motion state a discrete input or not)."""
    def rank(blocks: tuple[tuple[int, int], ...], space: int) -> tuple[tuple[int, int], ...]:
        def first_listed(block: tuple[int, int]) -> int:
            start, count = block
            for n, (reg, _) in enumerate(listed):
                if reg.space == space and start <= reg.register.address < start + count:
                    return n
            return len(listed)
        return tuple(sorted(blocks, key=first_listed))
    order = list(dict.fromkeys(reg.space for reg, _ in listed))
    return replace(
        plan, blocks=rank(plan.blocks, 0), input_blocks=rank(plan.input_blocks, 1),
        coil_blocks=rank(plan.coil_blocks, 2), discrete_blocks=rank(plan.discrete_blocks, 3),
        space_order=(*order, *(s for s in (0, 1, 2, 3) if s not in order)))


def _static_target(d: Description, key: str) -> Register:
    m = _TARGET.fullmatch(key.strip())
    if m is None:
        raise ConfigError(f"{d.family}: {key!r} is not a register")
    reg = d.regs[m.group(1)]
    return reg.at(int(m.group(2), 0)) if m.group(2) is not None else reg.register


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
        "pulses_per_rev_allowed": _ppr_allowed(d),
        "addresses": link.address_set,
        "line_kinds": link.line_kinds,
        "baud_rates": tuple(link.baud_rates),
        "line_formats": tuple(link.formats),
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
        from drivebus.drives.cia402_engine import Cia402Profile, cia402_attrs

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
                                comms=reg.d.comms))
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
