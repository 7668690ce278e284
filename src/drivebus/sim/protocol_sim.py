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
import os
import socket
import termios

import serial
from serial.serialposix import Serial as PosixSerial

__all__ = ["serial_class_for_url"]


class _SimPort(PosixSerial):
    """A POSIX serial port on a virtual wire's pty; it takes the line's master seat while
    it is open (``drivebus.sim.masters``: a second master on the line is refused)."""

    wire = None  # set per wire by serial_class_for_url

    def open(self) -> None:
        """Take the line's seat, then open the pty."""
        from drivebus.sim.masters import describe_process

        wire = self.wire
        if wire is not None:
            refused = wire.seat.take(self, f"{describe_process(os.getpid())}, this one,")
            if refused is not None:
                raise serial.SerialException(refused)
        try:
            super().open()
        except BaseException:
            if wire is not None:
                wire.seat.free(self)
            raise

    def close(self) -> None:
        """Close the pty and free the line's seat."""
        super().close()
        if self.wire is not None:
            self.wire.seat.free(self)

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


class _RemoteSimPort(PosixSerial):
    """A POSIX serial port on the pty of a ``drivebus sim`` in another process: the byte
    size and parity go to its wire through the line's format channel (a Unix socket).

    The first format is answered before the port is used (it seats this master, or says
    who has the line). A later one (a line whose drives run different formats switches
    per request) is sent without waiting: the wire reads the channel before every read
    of the pty, so the next frame is judged at that format, and a port switching format
    never holds its event loop on the other process (a stop waits for no answer)."""

    channel = ""  # set per line by serial_class_for_url
    _told: tuple[int, str] | None = None
    _sock: socket.socket | None = None

    def _reconfigure_port(self, force_update: bool = False) -> None:
        bytesize, parity = self._bytesize, self._parity
        self._bytesize, self._parity = serial.EIGHTBITS, serial.PARITY_NONE
        try:
            super()._reconfigure_port(force_update)
        finally:
            self._bytesize, self._parity = bytesize, parity
        if (bytesize, parity) != self._told:
            if self._sock is None:
                self._seat(int(bytesize), str(parity))
            else:
                self._switch(int(bytesize), str(parity))

    def _seat(self, bytesize: int, parity: str) -> None:
        """Tell the first format and wait for the answer: the line's seat is this
        master's, or ``SerialException`` says who has it."""
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        answer = b""
        try:
            sock.settimeout(2.0)
            sock.connect(self.channel)
            sock.sendall(f"F {bytesize} {parity}\n".encode())
            while not answer.endswith(b"\n") and len(answer) < 1024:
                chunk = sock.recv(1024)
                if not chunk:
                    break
                answer += chunk
        except OSError as exc:
            sock.close()
            raise serial.SerialException(
                f"the simulated line's format channel {self.channel} does not answer: {exc}"
            ) from exc
        if answer != b"ok\n":
            sock.close()
            if answer.startswith(b"busy "):  # another master has the line (sim.masters)
                raise serial.SerialException(answer[5:].decode(errors="replace").strip())
            raise serial.SerialException(f"the simulated line refused format {bytesize}"
                                         f"{parity}: {answer!r}")
        sock.setblocking(False)
        self._sock, self._told = sock, (bytesize, parity)

    def _switch(self, bytesize: int, parity: str) -> None:
        """Tell a later format without waiting (``f 8 E``: not answered)."""
        assert self._sock is not None
        message = f"f {bytesize} {parity}\n".encode()
        try:
            sent = self._sock.send(message)
        except OSError as exc:  # (BlockingIOError: the simulator has not read for long)
            raise serial.SerialException(
                f"the simulated line's format channel {self.channel} failed: {exc}") from exc
        if sent != len(message):
            raise serial.SerialException(
                f"the simulated line's format channel {self.channel} is full")
        self._told = (bytesize, parity)

    def close(self) -> None:
        """Close the pty and the format channel (the wire forgets the format)."""
        super().close()
        if self._sock is not None:
            self._sock.close()
            self._sock = None
            self._told = None


def serial_class_for_url(url: str) -> tuple[str, type[PosixSerial]]:
    """Resolve ``sim://NAME`` to the wire's pty path and a port class bound to the wire.

    A wire of this process is used with its format side channel; else the pty of a running
    ``drivebus sim`` in another process (published by ``drivebus.sim.serve``), whose
    format channel (a Unix socket) carries the parity and byte size a pty cannot. A URL
    that gives both (``sim://NAME?pty=PATH&channel=SOCKET``) names a wire of another
    process directly (a machine's private simulator, for a worker of that machine).
    """
    from drivebus.sim.serve import published
    from drivebus.sim.wire import lookup_wire

    name, _, query = url.split("://", 1)[1].partition("?")
    name = name.strip("/")
    options = dict(part.partition("=")[::2] for part in query.split("&") if part)
    if "pty" in options:  # a wire of another process, given by its pty and format channel
        channel = options.get("channel", "")
        if not channel:
            return options["pty"], PosixSerial
        return options["pty"], type("RemoteSimPort", (_RemoteSimPort,), {"channel": channel})
    try:
        wire = lookup_wire(name)
    except KeyError:
        found = published(name)
        if found is None or found.kind != "serial":
            raise serial.SerialException(
                f"no simulated line named {name!r} is running (a serial one; start it with "
                f"`drivebus sim CONFIG`, or open a machine whose line is sim://{name})"
            ) from None
        if found.channel is None:
            return found.where, PosixSerial
        return found.where, type("RemoteSimPort", (_RemoteSimPort,), {"channel": found.channel})
    return wire.slave_path, type("SimPort", (_SimPort,), {"wire": wire})
