"""pyserial URL handler for ``sim://NAME``: opens a running VirtualWire's pty.

pyserial finds this module through ``serial.protocol_handler_packages`` (drivebus adds
``drivebus.sim``). The port class is the ordinary POSIX serial port on the pty; it only
adds the side channel that tells the wire the byte size and parity. A pty carries baud
rate and stop bits to the other side but not parity or byte size (some kernels refuse
PARENB on a pty with EINVAL), so those two go to the pty as 8N and to the wire directly.
A wire may model an adapter that runs only some baud rates (``adapter_bauds``: the port
then sets the nearest one, as such an adapter's driver does) or formats
(``adapter_formats``: setting another fails with EINVAL, as ``tcsetattr`` does).
"""

from __future__ import annotations

import errno
import termios

import serial
from serial.serialposix import Serial as PosixSerial

__all__ = ["serial_class_for_url"]


class _SimPort(PosixSerial):
    """A POSIX serial port on a virtual wire's pty."""

    wire = None  # set per wire by serial_class_for_url

    def _reconfigure_port(self, force_update: bool = False) -> None:
        bytesize, parity, baudrate = self._bytesize, self._parity, self._baudrate
        formats = None if self.wire is None else self.wire.adapter_formats
        if formats is not None and f"{bytesize}{parity}{int(self._stopbits)}" not in formats:
            raise termios.error(errno.EINVAL, "Invalid argument")  # as tcsetattr refuses it
        self._bytesize, self._parity = serial.EIGHTBITS, serial.PARITY_NONE
        if self.wire is not None:  # the rate the simulated adapter's driver really sets
            self._baudrate = self.wire.adapter_baud(baudrate)
        try:
            super()._reconfigure_port(force_update)
        finally:
            self._bytesize, self._parity, self._baudrate = bytesize, parity, baudrate
        if self.wire is not None:
            self.wire.note_format(bytesize, parity)


def serial_class_for_url(url: str) -> tuple[str, type[PosixSerial]]:
    """Resolve ``sim://NAME`` to the wire's pty path and a port class bound to the wire.

    A wire of this process is used with its format side channel; else the pty of a running
    ``drivebus sim`` in another process (published by ``drivebus.sim.serve``), as a plain
    port: parity and byte size do not cross a pty, so keep to 8N1/8N2 there.
    """
    from drivebus.sim.serve import published_sim
    from drivebus.sim.wire import lookup_wire

    name = url.split("://", 1)[1].strip("/")
    try:
        wire = lookup_wire(name)
    except KeyError:
        path = published_sim(name)
        if path is None:
            raise serial.SerialException(
                f"no simulated line named {name!r} is running (start it with "
                f"`drivebus sim CONFIG`, or open a machine whose line is sim://{name})"
            ) from None
        return path, PosixSerial
    return wire.slave_path, type("SimPort", (_SimPort,), {"wire": wire})
