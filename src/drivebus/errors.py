"""Typed errors: every failure a caller can see is a ``DrivebusError`` subclass."""

from __future__ import annotations

from typing import ClassVar

__all__ = [
    "ArgumentError",
    "BusClosed",
    "ConfigError",
    "ConnectionLost",
    "DriveAlarm",
    "DriveOffline",
    "DrivebusError",
    "FrameError",
    "GroupMotionError",
    "InputTimeout",
    "LeaseHeld",
    "LimitViolation",
    "LineClosed",
    "LineConfigError",
    "LineNoise",
    "ModbusException",
    "MotionAborted",
    "MotionError",
    "MotionTimeout",
    "NotFound",
    "NotSupported",
    "PartialWrite",
    "ResponseTimeout",
    "ServiceUnreachable",
    "StateError",
    "TransactionError",
    "UnknownMethod",
    "WrongResponder",
    "leaf_errors",
]


class DrivebusError(Exception):
    """Base of every error drivebus raises on purpose."""


class ConfigError(DrivebusError, ValueError):
    """A setting, argument or config file is invalid; the message names it."""


class ArgumentError(DrivebusError, ValueError):
    """A call argument is invalid (not finite, not whole, negative, out of range); the
    message names the parameter, the value and what is allowed. Nothing was sent."""


class TransactionError(DrivebusError):
    """A Modbus transaction failed; ``slave`` is the address it was sent to."""

    def __init__(self, message: str, *, slave: int | None = None) -> None:
        super().__init__(message)
        self.slave = slave


class ResponseTimeout(TransactionError):
    """No complete reply arrived within the slave's response timeout."""


class FrameError(TransactionError):
    """A reply arrived but is unusable: bad CRC, short or malformed frame."""


class LineNoise(FrameError):
    """Bytes nobody asked for kept the line busy: noise, a babbling device, a slave at the
    wrong rate, or a network peer sending junk. ``line`` names the line.

    ``sent`` says whether the request went out: False, the line never went quiet for its
    silence within the request's timeout, so nothing was sent (a command was certainly
    not executed); True, it went out and its reply was drowned. The bus counts it in
    ``SlaveStats.line_noise`` and never waits past the request's timeout for a quiet
    line; the line recovers by itself once the noise stops.
    """

    def __init__(
        self, message: str, *, slave: int | None = None, line: str = "", sent: bool = True
    ) -> None:
        super().__init__(message, slave=slave)
        self.line = line
        self.sent = sent


class WrongResponder(TransactionError):
    """A valid frame arrived from another address than the one asked."""

    def __init__(self, message: str, *, slave: int | None = None, responder: int) -> None:
        super().__init__(message, slave=slave)
        self.responder = responder


class ModbusException(TransactionError):
    """The slave answered with a Modbus exception; ``text`` is the vendor's meaning."""

    STANDARD: ClassVar[dict[int, str]] = {
        1: "illegal function",
        2: "illegal data address",
        3: "illegal data value",
        4: "server device failure",
        5: "acknowledge",
        6: "server device busy",
        8: "memory parity error",
        10: "gateway path unavailable",
        11: "gateway target device failed to respond",
    }

    def __init__(
        self, code: int, *, function: int, slave: int | None = None, text: str | None = None,
        address: int | None = None, count: int = 1, registers: str = "",
    ) -> None:
        self.code = code
        self.function = function
        self.text = text or self.STANDARD.get(code, "unknown exception")
        self.address = address
        """The first address the request named (None: not known)."""
        self.count = count
        """How many registers (or bits) the request named."""
        self.registers = registers
        """The names of the registers at those addresses, as the drive's profile knows
        them ("" where none does)."""
        where = ""
        if address is not None:
            last = address + max(count, 1) - 1
            span = f"{address} (0x{address:04X})" if last == address else \
                f"{address}..{last} (0x{address:04X}..0x{last:04X})"
            where = f" at {span}" + (f": {registers}" if registers else "")
        super().__init__(
            f"slave {slave} answered function 0x{function:02X}{where} with exception "
            f"0x{code:02X}: {self.text}",
            slave=slave,
        )


class ConnectionLost(TransactionError):
    """The connection of a networked line dropped, or could not be re-established yet.

    The line reconnects by itself (at once after a drop, then with backoff); a request
    that was in flight may or may not have reached the device.
    """


class LineConfigError(TransactionError, ConfigError):
    """The line cannot carry this request as asked (e.g. per-slave serial settings on a
    serial server whose port has one setting). A ``ConfigError`` for callers, and a
    ``TransactionError`` so that the bus fails only this request, not the whole line."""


class LineClosed(DrivebusError):
    """The line or bus is closed (or closing); the request was not sent."""


BusClosed = LineClosed


class NotSupported(DrivebusError):
    """The drive cannot do this over its bus; the message names drive and function."""


class UnknownMethod(NotSupported, ConfigError):
    """A method (homing) the drive does not document was named: the drive cannot do it,
    and naming it is a configuration mistake; the message lists the methods it has."""


class PartialWrite(DrivebusError):
    """A series of writes (a parameter load) stopped part-way: ``written`` names what the
    drive took before it stopped, in order; the message says what was not written."""

    def __init__(self, message: str, *, written: list[str]) -> None:
        super().__init__(message)
        self.written = written


class DriveAlarm(DrivebusError):
    """The drive reports an alarm; ``code`` and ``text`` are the drive's own."""

    def __init__(self, message: str, *, code: int | None = None, text: str = "") -> None:
        super().__init__(message)
        self.code = code
        self.text = text


class DriveOffline(DrivebusError):
    """The drive stopped answering."""


class LimitViolation(DrivebusError):
    """A target or value lies outside a soft limit or a register's range."""


class StateError(DrivebusError):
    """The command is not allowed in the axis's current state."""


class MotionTimeout(DrivebusError):
    """A motion did not complete within the time its distance, speed and ramps allow."""


class InputTimeout(DrivebusError):
    """A digital input did not reach the awaited state in time (``Axis.wait_input``)."""


class MotionAborted(DrivebusError):
    """Another command (a stop, an emergency stop, a new motion) ended this motion."""


class MotionError(DrivebusError):
    """The drive stopped or refused a motion without an alarm (e.g. stopped short)."""


class GroupMotionError(DrivebusError):
    """One axis of a group failed; the others were stopped. ``axis`` names the culprit
    (the failure itself is the ``__cause__``)."""

    def __init__(self, message: str, *, axis: str) -> None:
        super().__init__(message)
        self.axis = axis


class NotFound(DrivebusError, LookupError):
    """No such axis, line or motion; the message names what was asked and what exists."""


class LeaseHeld(DrivebusError):
    """Another client holds the machine's command lease; ``holder`` names it (an
    emergency stop is never refused by a lease)."""

    def __init__(self, message: str, *, holder: str) -> None:
        super().__init__(message)
        self.holder = holder


class ServiceUnreachable(DrivebusError):
    """A ``drivebus serve`` that should own the machine could not be reached."""


def leaf_errors(exc: BaseException) -> list[BaseException]:
    """The errors inside ``exc``, in order: task groups wrap them in (nested) exception
    groups, and a front end reports each cause on its own."""
    if isinstance(exc, BaseExceptionGroup):
        return [leaf for e in exc.exceptions for leaf in leaf_errors(e)]
    return [exc]
