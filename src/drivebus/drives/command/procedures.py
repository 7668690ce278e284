"""Running a description's procedures: first dry, without I/O (every value it writes
range-checked before the first frame), then step by step (writes, reads, modify,
calls, checks, bounded waits, state, fail, return); its own procedures as methods.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping, Sequence
from typing import Any

import anyio

from drivebus.bus import Priority
from drivebus.drives.command.base import ProfileBase
from drivebus.drives.command.runs import _DEFAULT_PRIORITY, _MAX_DEPTH, _PRIORITY, _Run
from drivebus.drives.description import PROCEDURES, Procedure, Step
from drivebus.drives.expr import Unknown
from drivebus.drives.values import Unread
from drivebus.errors import ConfigError, DriveAlarm, LimitViolation, MotionError, StateError


class Procedures(ProfileBase):
    """A procedure run dry, then step by step."""

    async def run(self, name: str, *args: Any, **kwargs: Any) -> Any:
        """Run procedure ``name`` with its parameters (positional or by name)."""
        return await self._run(name, self._call(name, args, kwargs))

    def dry_run(self, name: str, **kwargs: Any) -> None:
        """Check procedure ``name`` with these parameters as ``run`` would before its first
        frame (``NotSupported``, a value out of its register's range), sending nothing."""
        call = self._call(name, (), kwargs)
        proc = self._procedure(name, call)
        home = self._home_attrs(call) if name == "home" else None
        self._dry(proc, _Run(name, dict(call), True, self._priority(name, proc), 0, home=home))

    def _call(self, name: str, args: Sequence[Any], kwargs: Mapping[str, Any]
              ) -> dict[str, Any]:
        """The parameters of a call of procedure ``name``, by name, defaults filled in."""
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
        return call

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
                    if self._decided_now(step):
                        self._fail(step, run)
                    break  # else raised for real by the run
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
            self._fail(step, run)
        elif action == "return":
            assert step.return_ is not None
            run.result = step.return_(self._scope(run))

    def _fail(self, step: Step, run: _Run) -> None:
        """Raise the ``NotSupported`` a ``fail`` step says."""
        assert step.fail is not None
        raise self.unsupported(self._what(run.proc, self.description.procedures.get(
            run.proc), run.args), step.fail(self._scope(run)))

    def _decided_now(self, step: Step) -> bool:
        """Whether a dry run may raise ``step`` (a ``fail`` whose condition held): only
        where that condition uses no state but what ``learn`` sets, and the drive has been
        learned (a refusal decided from reads, before the set-up writes; state the set-up
        itself sets is known only after it)."""
        if not self._learned:
            return False
        learn = self.description.procedures.get("learn")
        learned = {f"state.{k}" for st in (learn.steps if learn else []) if st.set
                   for k in st.set}
        used = step.when.paths if step.when is not None else frozenset()
        return all(p in learned for p in used if p.startswith("state."))

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
