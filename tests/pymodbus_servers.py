"""pymodbus's own servers as third-party peers, across the pymodbus versions we test on.

pymodbus 3.13 and later serve ``SimDevice`` lists; older releases (and 3.12, whose
``SimDevice`` answers exception 04 where 02 is due) serve a ``ModbusServerContext`` of
device contexts, which 3.16 deprecates. ``server_data`` gives each what it serves.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from importlib.metadata import version

__all__ = ["PYMODBUS", "server_data"]


def _parse(text: str) -> tuple[int, int]:
    major, minor = text.split(".")[:2]
    return int(major), int("".join(c for c in minor if c.isdigit()))


PYMODBUS = _parse(version("pymodbus"))
"""(major, minor) of the installed pymodbus."""


def server_data(devices: Mapping[int, Sequence[int]]) -> object:
    """What a pymodbus server takes as its first argument to serve ``devices``: unit id
    to its holding registers, from address 0 (reads past them: exception 02)."""
    if PYMODBUS >= (3, 13):
        from pymodbus.simulator import DataType, SimData, SimDevice

        return [
            SimDevice(unit, simdata=[SimData(0, values=list(regs), datatype=DataType.REGISTERS)])
            for unit, regs in devices.items()
        ]
    from pymodbus.datastore import ModbusSequentialDataBlock, ModbusServerContext

    try:
        from pymodbus.datastore import ModbusDeviceContext as Context  # 3.10 ..
    except ImportError:
        from pymodbus.datastore import ModbusSlaveContext as Context  # .. 3.9
    # The device contexts look address n up at n + 1: the block starts at 1 for address 0.
    # All four tables are given: 3.9 and 3.10 ignore hr= unless di= is given too.
    contexts = {
        unit: Context(
            di=ModbusSequentialDataBlock(1, [0]), co=ModbusSequentialDataBlock(1, [0]),
            ir=ModbusSequentialDataBlock(1, [0]), hr=ModbusSequentialDataBlock(1, list(regs)),
        )
        for unit, regs in devices.items()
    }
    return ModbusServerContext(contexts, single=False)
