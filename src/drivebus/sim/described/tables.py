"""A described twin's position table (``do = "run_table"``): rows of moves and waits,
run once or repeated, stopped by a limit switch.
"""

from __future__ import annotations

from typing import Any

from drivebus.drives.description import Trigger
from drivebus.sim.described.base import TwinBase, _usable
from drivebus.sim.described.state import _TableRun


class Tables(TwinBase):
    """A table of moves under way."""

    def _start_table(self, trig: Trigger, value: Any, now: float) -> None:
        """Run rows 1..``rows``: each a move (``target``, or ``distance`` where the target
        is None) at its speed and rates, then its ``wait``; the last row's wait only when
        the table repeats. The drive reports moving from start to end, waits included; a
        limit switch met stops the motor (as ``[twin] limits`` say) and the table."""
        rows = int(self._param(trig, "rows", now, value) or 0)
        if rows <= 0:
            return
        repeat = bool(self._param(trig, "repeat", now, value))
        self._wrap(now)
        self._table = _TableRun(trig, value, rows, repeat)
        self.motion = trig.motion or "table"
        self.stopping = None
        self._homing = None
        self._ref = None
        self.reached = False
        self._completes = False
        self._processed_until = max(self._processed_until, now)
        self._table_row(now)

    def _row(self, name: str, t: float) -> Any:
        """A row expression of the running table, with ``row`` its number (from 1)."""
        tr = self._table
        assert tr is not None
        e = getattr(tr.trig, name)
        return None if e is None else self._eval(e, t, tr.value, {"row": tr.row + 1})

    def _table_move(self, t: float) -> bool:
        """Start the present row's move; False if it has none (no distance, no speed)."""
        tr = self._table
        assert tr is not None
        ppr = self.pulses_per_rev
        speed, accel = self._row("speed", t), self._row("accel", t)
        decel = self._row("decel", t) if tr.trig.decel is not None else accel
        here = self.kin.position(t)
        target = self._row("target", t)
        if target is None and tr.trig.distance is not None:
            target = round(here) + float(self._row("distance", t))
        if target is None or not _usable(speed, accel, decel) or \
                abs(float(target) - here) < 0.5:
            return False
        if self._blocked(float(target) - here, t):
            self._table_end(t)
            return True
        a, dc = float(accel) * ppr, float(decel) * ppr
        self.kin.move_to(t, float(target), self._pps(abs(float(speed))), a, dc)
        self._motion_decel = dc
        self._last_dir = 1 if float(target) > here else -1
        tr.phase = "move"
        return True

    def _table_wait(self, t: float) -> bool:
        """Begin the present row's wait, if it has one (the last row's only when the
        table repeats)."""
        tr = self._table
        assert tr is not None
        if tr.row == tr.rows - 1 and not tr.repeat:
            return False
        wait = float(self._row("wait", t) or 0.0)
        if wait <= 0:
            return False
        tr.phase, tr.until = "wait", t + wait
        return True

    def _table_next(self, t: float) -> bool:
        """Go on to the next row (the first again when it repeats); False at the end."""
        tr = self._table
        assert tr is not None
        tr.row += 1
        if tr.row >= tr.rows:
            if not tr.repeat:
                self._table_end(t)
                return False
            tr.row = 0
        return True

    def _table_row(self, t: float) -> None:
        """Run rows from the present one until one moves or waits (a whole pass without
        either ends the table)."""
        tr = self._table
        assert tr is not None
        for _ in range(tr.rows + 1):
            if self._table_move(t) or self._table_wait(t) or not self._table_next(t):
                return
        self._table_end(t)

    def _table_moved(self, t: float) -> None:
        if not self._table_wait(t) and self._table_next(t):
            self._table_row(t)

    def _table_waited(self, t: float) -> None:
        if self._table_next(t):
            self._table_row(t)

    def _table_limit(self, t: float) -> None:
        self.kin.stop(t, self._limit_rate(t))
        self.stopping = "limit"
        self._table = None

    def _table_end(self, t: float) -> None:
        self._table = None
        self.reached = True
