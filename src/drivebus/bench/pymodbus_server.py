"""pymodbus's own Modbus TCP server in a process of its own, for the pipelined-TCP bench.

``python -m drivebus.bench.pymodbus_server`` serves unit 1 (200 holding registers) on a
free loopback port, prints the port on its first line and serves until stdin closes.

pymodbus 3.16's request handler decodes one request per read and keeps only the last
one decoded, so requests that arrive together (pipelined) wait for the next read, or are
lost or answered twice with one id. Here every request of a read is decoded, queued and
answered in turn, as a device that accepts several requests in flight does; the rest is
pymodbus's own server.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import sys

__all__ = ["main"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _queue_every_request() -> None:
    """Make pymodbus's server handler answer every request of a read, in order."""
    import pymodbus.server.base as base
    from pymodbus.server.requesthandler import ServerRequestHandler
    from pymodbus.transaction import TransactionManager

    class PipelinedHandler(ServerRequestHandler):  # type: ignore[misc]
        def callback_data(self, data: bytes, addr: tuple[str, int] | None = None) -> int:
            used = 0
            while True:  # every complete request of the buffer, not just the first
                used += int(TransactionManager.callback_data(self, data[used:], addr))
                if not self.last_pdu:
                    return used
                pending = getattr(self, "pending", None)
                if pending is None:
                    pending = self.pending = asyncio.Queue()
                    self.worker = self.loop.create_task(self.answer_in_turn())
                pending.put_nowait((self.last_pdu, self.last_addr))

        async def answer_in_turn(self) -> None:
            while True:
                self.last_pdu, self.last_addr = await self.pending.get()
                await self.handle_request()

    base.ServerRequestHandler = PipelinedHandler


async def _serve() -> None:
    from pymodbus.server import ModbusTcpServer
    from pymodbus.simulator import DataType, SimData, SimDevice

    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    _queue_every_request()
    port = _free_port()
    device = SimDevice(id=1, simdata=[SimData(0, count=200, values=7, datatype=DataType.REGISTERS)])
    server = ModbusTcpServer(device, address=("127.0.0.1", port))
    await server.serve_forever(background=True)
    try:
        print(port, flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
    finally:
        await server.shutdown()


def main() -> None:
    """Serve until stdin closes."""
    asyncio.run(_serve())


if __name__ == "__main__":
    main()
