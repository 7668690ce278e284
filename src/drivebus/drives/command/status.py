"""Reads and what they decode to: a plan's words read and decoded through the codecs,
the status poll decoded into ``DriveStatus`` as ``[status]`` says, alarm texts,
signals, the completion read, the drive's identity.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from drivebus.bus import Priority
from drivebus.clock import monotonic
from drivebus.drives.command.base import ProfileBase
from drivebus.drives.command.decoding import Decoding
from drivebus.drives.command.reads import OBJECT, ReadPlan, Span, _in_span, plan_reads
from drivebus.drives.command.runs import _Run
from drivebus.drives.description import Description, Reg
from drivebus.drives.expr import Expr, ExprError, Unknown
from drivebus.drives.programs import Completion
from drivebus.drives.status import DriveIdentity, DriveStatus
from drivebus.drives.units import Kind
from drivebus.drives.values import Attrs, Table, Unread, reg_value
from drivebus.errors import ConfigError


class Status(ProfileBase):
    """Reads decoded; the status, completion, signals and identity."""

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
        if plan is self._status_plan:  # the poll: its decoding made once (``Decoding``)
            decoding = self.__dict__.get("_status_decoding")
            if decoding is None or decoding.ppr != self.pulses_per_rev:
                decoding = self.__dict__["_status_decoding"] = Decoding(
                    plan, self.pulses_per_rev)
            return decoding.decode(self.description, self.last, words, raw_words)
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

    async def read_status(self, *, priority: Priority = Priority.POLL) -> DriveStatus:
        """The status poll, decoded as the description says."""
        if not self._learned and self.description.status.learn_first:
            # (a setup cut short by a stop leaves it to learn again): at the poll's own
            # priority, so an emergency poll inside a hold does not wait for its end
            await self.learn(priority=max(priority, Priority.CONFIG))
        raw_words: dict[str, list[int]] = {}
        requested = monotonic()
        values = await self._poll_values(self._status_plan, priority, raw_words)
        try:
            scope: dict[str, Any] | None = None
            for when, plan in self._extra_plans:
                if scope is None:
                    scope = self._scope(None, values)
                if when(scope):
                    values.update(await self._poll_values(plan, priority, raw_words))
                    scope = None  # made again with what the extra read brought
            await self._read_due_signals(priority)
            if type(self).decode_status is not Status.decode_status:
                return self.decode_status(values, raw_words, requested_at=requested)
            return self._decode_status(values, raw_words, requested, scope)
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
        return self._decode_status(values, raw_words, requested_at, None)

    def _decode_status(self, values: Mapping[str, Any],
                       raw_words: Mapping[str, list[int]] | None,
                       requested_at: float | None, scope: dict[str, Any] | None
                       ) -> DriveStatus:
        """``decode_status``, with the scope of ``values`` if the caller has it: one scope
        per poll (its ``state.NAME`` reads the profile's state itself, so what the trackers
        update is seen by the fields without making it again)."""
        d = self.description
        s = d.status
        fields = d.status_exprs
        if scope is None:
            scope = self._scope(None, values)
        scope["words"] = Attrs("words", dict(raw_words or {}))
        if s.track and self.fresh(requested_at):  # trackers first: the fields see them
            updates = {k: e(scope) for k, e in s.track.items()}
            self.state.update(updates)

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
        raw = raw_values(s.raw, scope) if s.raw else polled_raw(d, values, raw_words)
        return DriveStatus(
            enabled=flag("enabled"),
            moving=flag("moving"),
            in_position=flag("in_position"),
            homed=flag("homed") if "homed" in fields else self.homed_here,
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


def raw_values(raw: Mapping[str, Expr], scope: Mapping[str, Any]) -> dict[str, int]:
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


def polled_raw(d: Description, values: Mapping[str, Any],
               raw_words: Mapping[str, list[int]] | None) -> dict[str, int]:
    """Each polled register's own value, what its words hold before scale and unit (a
    speed in 0.1 rpm, a ramp in ms, a count scaled by 2); without the words, the values
    that are integers."""
    out: dict[str, int] = {}
    for k, v in values.items():
        ws = raw_words.get(k) if raw_words is not None else None
        if ws is not None:
            out[k] = d.regs[k].at(None).decode(ws)
        elif isinstance(v, int):
            out[k] = int(v)
    return out


def _physical(e: Expr, scope: Mapping[str, Any], d: Description, what: str) -> Any:
    """A status field's value: a register's physical value, or the expression's."""
    v = e(scope)
    if isinstance(v, Unread):
        raise Unknown(f"status.{what}: register {v.key} was not polled")
    return v
