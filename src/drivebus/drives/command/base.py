"""The command engine's state: the description it runs, its options, state variables,
what it learned and last wrote, which procedures it has, and the names an expression
sees (``_scope``).
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property
from typing import Any, ClassVar

from drivebus.bus import SlaveHandle
from drivebus.drives.base import DriveProfile
from drivebus.drives.command.reads import ReadPlan
from drivebus.drives.command.runs import _Last, _Run
from drivebus.drives.description import Description, Procedure
from drivebus.drives.description.mapping import register_namer
from drivebus.drives.expr import Expr, ExprError, Unknown
from drivebus.drives.registers import Register
from drivebus.drives.values import Attrs, FunctionNames, IoSignals, Unread


class ProfileBase(DriveProfile):
    """The command engine's state: the description, its options, state variables,
    what it learned and last wrote, and the names an expression sees. The rooms
    (``procedures``, ``writes``, ``status``, ``setup``, ``motion``, ``homing``,
    ``programs``) add what it does; ``DescribedProfile`` is them all."""

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
        self.homed_here = False
        """A homing by a method that sets the position at once (``behaviour = "set"``)
        ran here since the drive was set up: the status's ``homed`` where the description
        decodes none (a drive without a homed flag)."""
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

    @cached_property
    def tracked(self) -> frozenset[str]:
        """``enabled`` where the description's reads only ``state`` (what the profile last
        commanded); ``homed`` where it has none (a homing that set the position here) or
        one that reads only ``state``."""
        fields = self.description.status_exprs
        drive = {*self.description.regs, "words", "input", "output"}
        out = set()
        for name in ("enabled", "homed"):
            e = fields.get(name)
            if (e is None and name == "homed") or (
                    e is not None and "state" in e.names and not e.names & drive):
                out.add(name)
        return frozenset(out)

    def restarted(self) -> None:
        """The state variables start again from the description's ``[state]`` (what
        ``learn`` set is read again by the next setup); no homing was done here."""
        self.state.clear()
        self.state.update(self.description.state)
        self.homed_here = False

    def _steps_of(self, name: str) -> Procedure | None:
        """The description's procedure ``name`` where it has steps (None: absent, or
        marked unsupported)."""
        proc = self.description.procedures.get(name)
        return proc if proc is not None and proc.unsupported is None else None

    def _procedure(self, name: str, args: Mapping[str, Any]) -> Procedure:
        d = self.description
        proc = d.procedures.get(name)
        what = self._what(name, proc, args)
        if proc is None:  # say where it would be: a page and an error with a reason
            raise self.unsupported(what, f"its description has no [procedures.{name}]")
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
