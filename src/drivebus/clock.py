"""Sub-millisecond sleeps for the wire's silences.

asyncio's own timers wake through ``epoll_wait``, whose timeout has 1 ms granularity, so
a 1.75 ms silence would cost 2-3 ms. On Linux a timerfd armed at an absolute
CLOCK_MONOTONIC time (the clock behind ``time.monotonic``) makes the loop's selector wake
within tens of microseconds instead; elsewhere we fall back to ``asyncio.sleep``.
"""

from __future__ import annotations

import asyncio
import ctypes
import ctypes.util
import os
import sys
import threading
import time
from collections.abc import Callable

__all__ = [
    "STALL",
    "STALL_GRACE",
    "DeadlineTimer",
    "PreciseTimer",
    "StolenSince",
    "cpu_stolen",
    "cpu_wait",
    "cpu_wait_of",
    "cpu_wait_stamp",
    "monotonic",
    "stall_grace",
]

monotonic = time.monotonic

STALL = 0.002
"""A timer that runs this much after its time or later was held up, and a thread that
waited this long for a CPU was held up: the process (or its event loop) was not running."""
STALL_GRACE = 0.02
"""How much longer a reply is waited for, beyond the time lost, when the process was held
up while it waited: a few scheduler slices, a starved peer's turnaround."""
_GRACE_MAX = 1.0

_SCHEDSTAT = threading.local()


def cpu_wait() -> float:
    """Seconds this thread has spent ready to run but waiting for a CPU, a running total
    (Linux's ``/proc/thread-self/schedstat``); 0.0 where the kernel does not say."""
    return cpu_wait_of(cpu_wait_stamp())


def cpu_wait_stamp() -> bytes:
    """What ``cpu_wait`` is read from, as the kernel gave it (one read, nothing parsed):
    ``cpu_wait_of`` makes it seconds. For a mark taken per transaction and rarely needed
    (a reply deadline's start)."""
    fd = getattr(_SCHEDSTAT, "fd", None)
    if fd is None:
        try:
            fd = os.open("/proc/thread-self/schedstat", os.O_RDONLY | os.O_CLOEXEC)
        except OSError:
            fd = -1
        _SCHEDSTAT.fd = fd
    if fd < 0:
        return b""
    try:
        return os.pread(fd, 64, 0)
    except OSError:
        return b""


def cpu_wait_of(stamp: bytes) -> float:
    """The seconds of ``cpu_wait`` in a ``cpu_wait_stamp`` (0.0 for an empty one)."""
    try:
        return int(stamp.split()[1]) / 1e9
    except (ValueError, IndexError):
        return 0.0


_HZ = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def cpu_stolen() -> float:
    """Seconds a virtual machine's hypervisor has taken this machine's CPUs away so far,
    all CPUs added up (Linux's ``/proc/stat`` steal; 0.0 where the kernel does not say).
    A thread's CPU clock there counts that time as the thread's own: a 1 ms piece of work
    measured up to 38 ms of thread CPU time on a loaded 2-core VM, every time with steal
    ticks (10 ms each) over it, and never without."""
    try:
        with open("/proc/stat", "rb") as f:
            return int(f.readline().split()[8]) / _HZ
    except (OSError, IndexError, ValueError):
        return 0.0


class StolenSince:
    """``cpu_stolen`` as it was shortly before now, for code that times many short pieces
    (event-loop steps): ``mark()`` per piece reads ``/proc/stat`` again only once the last
    reading is ``FRESH`` seconds old (a read per piece costs more than most pieces), and
    ``since(mark)`` says how much a piece that turned out slow had taken away."""

    FRESH = 0.005

    def __init__(self) -> None:
        self._value = cpu_stolen()
        self._at = time.perf_counter()

    def mark(self) -> float:
        """The stolen time at about now (at most ``FRESH`` old)."""
        now = time.perf_counter()
        if now - self._at > self.FRESH:
            self._value, self._at = cpu_stolen(), now
        return self._value

    @staticmethod
    def since(mark: float) -> float:
        """Seconds stolen since ``mark`` (a little more: the mark may be a bit old)."""
        return cpu_stolen() - mark


def stall_grace(late: float, waited: float = 0.0) -> float:
    """How much longer to wait for a reply whose deadline has come: 0 (decide now) if the
    process ran all along, else the time it lost plus ``STALL_GRACE``.

    ``late``: how long after the deadline its timer ran; ``waited``: how long the thread
    waited for a CPU since the request went out, or shortly before (``cpu_wait``; see
    ``drivebus.line.receiver.CPU_WAIT_MARK_AGE``). A deadline that passed
    while the process was not running was not watched: a peer in the same process (a
    simulated drive) did not run either, and may not even have read the request. It gets
    back the time it lost and a moment to answer (a peer that ran all along has had its
    whole timeout). Owners extend a deadline a bounded number of times, so a dead peer
    still times out on a busy machine.
    """
    if late < STALL and waited < STALL:
        return 0.0
    return min(waited + STALL_GRACE, _GRACE_MAX)

_CLOCK_MONOTONIC = 1
_TFD_NONBLOCK = os.O_NONBLOCK
_TFD_CLOEXEC = 0o2000000
_TFD_TIMER_ABSTIME = 1
_C_ABSTIME = ctypes.c_int(_TFD_TIMER_ABSTIME)
_C_RELATIVE = ctypes.c_int(0)
_PR_SET_TIMERSLACK = 29
_TIMER_SLACK_NS = 10_000


def spin_until(deadline: float) -> None:
    """Spin on the clock until ``time.monotonic()`` reaches ``deadline``: for the last few
    tens of microseconds before an action that must happen on time (no sleep is that
    precise), never for a longer wait."""
    while monotonic() < deadline:
        pass


class _Timespec(ctypes.Structure):
    _fields_ = (("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long))


class _Itimerspec(ctypes.Structure):
    _fields_ = (("it_interval", _Timespec), ("it_value", _Timespec))


def _load_libc() -> ctypes.CDLL | None:
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.timerfd_create  # noqa: B018 - probe that the symbol exists
    except (OSError, AttributeError):
        return None
    # The kernel rounds a normal thread's timers up by 50 us of "slack"; ask for 10 us.
    libc.prctl(_PR_SET_TIMERSLACK, _TIMER_SLACK_NS, 0, 0, 0)
    # timerfd_settime is called per transaction with ctypes objects made once (the
    # timer's descriptor, the flags, a reference to its spec): no argument types to
    # declare, nothing converted per call (the cheapest ctypes call; int arguments would
    # be converted, and a pointer passed as an int cut to 32 bits).
    return libc


_libc = _load_libc()


class PreciseTimer:
    """One re-armable timer per owner (a line, a simulated wire); not shared across tasks,
    and used in one event loop (``close()`` it before another uses it).

    The kernel and the event loop wake us some tens of microseconds after the timer
    fires. The timer therefore fires ``lead`` seconds early and the rest is spun on the
    clock; ``lead`` follows the median wake-up latency seen (shared by every timer of the
    process): each early wake-up shortens it by ``_STEP``, each late one lengthens it by as
    much. The spin then stays a few microseconds on an idle machine, and a wake-up that a
    busy machine delays by a millisecond counts as one late wake-up, not as a reason to
    spin hundreds of microseconds before every frame (which cannot make up for it).
    """

    lead = 50e-6
    _LEAD_MAX = 300e-6
    _STEP = 1e-6

    def __init__(self) -> None:
        self._fd: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._waiter: asyncio.Future[bool] | None = None
        """What ``sleep_until`` awaits: True if ``wake()`` ended it, False at its time."""
        self._spec = _Itimerspec()
        self._value = self._spec.it_value
        self._spec_ref = ctypes.byref(self._spec)
        self._c_fd = ctypes.c_int(-1)
        """``_fd`` as timerfd_settime takes it (see ``_load_libc``)."""
        self._callback: Callable[[], None] | None = None
        self._deadline = 0.0
        self._handle: asyncio.TimerHandle | None = None
        self._adapt_on_fire = False

    def _ensure(self) -> bool:
        if _libc is None:
            return False
        loop = asyncio.get_running_loop()
        if self._fd is not None and self._loop is loop:
            return True
        self.close()
        fd = _libc.timerfd_create(_CLOCK_MONOTONIC, _TFD_NONBLOCK | _TFD_CLOEXEC)
        if fd < 0:
            return False
        self._fd, self._loop = fd, loop
        self._c_fd = ctypes.c_int(fd)
        loop.add_reader(fd, self._fired)
        return True

    def _arm(self, deadline: float) -> None:
        sec = int(deadline)
        value = self._value
        value.tv_sec = sec
        ns = int((deadline - sec) * 1e9)
        value.tv_nsec = ns if ns > 0 else 1  # (all zero would disarm; no max(): per transaction)
        assert _libc is not None and self._fd is not None
        if _libc.timerfd_settime(self._c_fd, _C_ABSTIME, self._spec_ref, None):
            raise OSError(ctypes.get_errno(), "timerfd_settime failed")

    def _disarm(self) -> None:
        if self._fd is not None and _libc is not None:
            self._value.tv_sec = self._value.tv_nsec = 0
            _libc.timerfd_settime(self._c_fd, _C_RELATIVE, self._spec_ref, None)

    def _fired(self) -> None:
        try:
            os.read(self._fd, 8)  # type: ignore[arg-type]
        except BlockingIOError:
            return
        callback, self._callback = self._callback, None
        if callback is not None:
            deadline = self._deadline
            if monotonic() < deadline:  # ``_reach``, written out: it runs per transaction
                if self._adapt_on_fire:  # (no max(): per transaction)
                    lead = PreciseTimer.lead - PreciseTimer._STEP
                    PreciseTimer.lead = lead if lead > 0.0 else 0.0
                while monotonic() < deadline:
                    pass
            elif self._adapt_on_fire and monotonic() - deadline <= PreciseTimer._LEAD_MAX:
                # (late beyond the longest lead: the process waited for a CPU, see _reach)
                lead = PreciseTimer.lead + PreciseTimer._STEP  # (no min(): per transaction)
                PreciseTimer.lead = lead if lead < PreciseTimer._LEAD_MAX else \
                    PreciseTimer._LEAD_MAX
            callback()
            return
        waiter, self._waiter = self._waiter, None
        if waiter is not None and not waiter.done():
            waiter.set_result(False)

    def _call_now(self) -> None:
        """The fallback timer of ``call_at`` (no timerfd): asyncio's clock, then spin."""
        self._handle = None
        callback, self._callback = self._callback, None
        if callback is not None:
            self._reach(self._deadline, adapt=False)
            callback()

    def call_at(self, deadline: float, callback: Callable[[], None]) -> None:
        """Call ``callback`` from the event loop once ``time.monotonic()`` has reached
        ``deadline`` (at once if it has). It replaces whatever this timer had armed: one
        timer per owner. The callback runs right at the deadline, with no task switch
        after it: for an action that must follow a silence as closely as possible."""
        if self._callback is not None:
            self.cancel()
        now = monotonic()
        if deadline <= now:
            callback()
            return
        precise = self._fd is not None or self._ensure()
        self._callback = callback
        self._deadline = deadline
        if precise:
            lead = PreciseTimer.lead
            self._adapt_on_fire = deadline - now > lead
            at = deadline - lead
            self._arm(at if at > now + 1e-6 else now + 1e-6)  # (no max(): per transaction)
        else:
            loop = asyncio.get_running_loop()
            self._handle = loop.call_at(deadline - now + loop.time(), self._call_now)

    def cancel(self) -> None:
        """Forget the callback armed by ``call_at``, if it has not run."""
        if self._callback is None:
            return
        self._callback = None
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None
        else:
            self._disarm()

    async def sleep_until(self, deadline: float) -> None:
        """Return once ``time.monotonic()`` has reached ``deadline``, or as soon as
        ``wake()`` is called (then before it, and without spinning toward it)."""
        delay = deadline - monotonic()
        if delay <= 0:
            return
        fallback = self._fd is None and not self._ensure()
        loop = asyncio.get_running_loop()
        waiter: asyncio.Future[bool] = loop.create_future()
        self._waiter = waiter
        lead = PreciseTimer.lead
        if fallback:
            handle = loop.call_later(delay, self._timed_out)
        else:
            self._arm(max(deadline - lead, monotonic() + 1e-6))
        try:
            woken = await waiter
        finally:
            if fallback:
                handle.cancel()
            if self._waiter is waiter:
                self._waiter = None
                if not fallback:
                    self._disarm()
        if not woken:  # (woken: the owner re-plans now; the deadline may not matter any more)
            self._reach(deadline, adapt=not fallback and delay > lead)

    def _timed_out(self) -> None:
        """The fallback timer of ``sleep_until`` (no timerfd): its time has come."""
        waiter, self._waiter = self._waiter, None
        if waiter is not None and not waiter.done():
            waiter.set_result(False)

    @staticmethod
    def _reach(deadline: float, *, adapt: bool) -> None:
        """Spin to ``deadline`` if we woke early; with ``adapt``, move ``lead`` toward the
        median wake-up latency (a wait shorter than the lead says nothing about it)."""
        if monotonic() < deadline:
            if adapt:  # woke before the deadline: the lead is more than the latency
                lead = PreciseTimer.lead - PreciseTimer._STEP  # (no max(): per wait)
                PreciseTimer.lead = lead if lead > 0.0 else 0.0
            while monotonic() < deadline:
                pass
        elif adapt and monotonic() - deadline <= PreciseTimer._LEAD_MAX:
            # Woke late: lengthen the lead a step. A wake-up later than the longest lead is
            # the process waiting for a CPU, not the timer's latency (a longer lead cannot
            # help it): left out, or on a busy machine the lead would sit at its maximum
            # and every timer would spin that long.
            lead = PreciseTimer.lead + PreciseTimer._STEP
            PreciseTimer.lead = lead if lead < PreciseTimer._LEAD_MAX else \
                PreciseTimer._LEAD_MAX

    def wake(self) -> None:
        """End the sleep in progress now (the owner has something more urgent to do):
        ``sleep_until`` returns at once, not at its deadline."""
        waiter, self._waiter = self._waiter, None
        if waiter is not None and not waiter.done():
            waiter.set_result(True)

    def close(self) -> None:
        """Release the timer's file descriptor."""
        self.cancel()
        if self._fd is not None:
            if self._loop is not None and not self._loop.is_closed():
                self._loop.remove_reader(self._fd)
            os.close(self._fd)
            self._fd = None
            self._loop = None


class DeadlineTimer(PreciseTimer):
    """A re-armable timer for deadlines that may be met late but never early (a reply's
    timeout): the kernel's timerfd at the deadline itself, no lead and no spin. Unlike an
    asyncio timer it costs the event loop nothing on its other turns (a scheduled handle
    makes every turn read the clock and work out its timeout). Its callback runs from the
    event loop, never from ``call_at`` itself."""

    def call_at(self, deadline: float, callback: Callable[[], None]) -> None:
        """Call ``callback`` from the event loop once ``time.monotonic()`` has reached
        ``deadline``, in place of whatever this timer had armed."""
        precise = self._fd is not None or self._ensure()  # (before: it may cancel)
        self._callback = callback
        self._deadline = deadline
        if precise:
            self._arm(deadline)  # (a deadline that has passed fires at once)
            return
        if self._handle is not None:
            self._handle.cancel()
        loop = asyncio.get_running_loop()
        self._handle = loop.call_at(deadline - monotonic() + loop.time(), self._call_now)

    def _fired(self) -> None:
        try:
            os.read(self._fd, 8)  # type: ignore[arg-type]
        except BlockingIOError:
            return
        callback, self._callback = self._callback, None
        if callback is not None:
            callback()

    def _call_now(self) -> None:
        self._handle = None
        callback, self._callback = self._callback, None
        if callback is not None:
            callback()
