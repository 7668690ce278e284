"""The bus scheduler: priorities, retries, statistics, slave handles."""

from drivebus.bus.observe import Transaction, TransactionObserver
from drivebus.bus.priority import Priority
from drivebus.bus.scheduler import Bus
from drivebus.bus.slave import SlaveHandle
from drivebus.bus.stats import BusStats, SlaveStats

__all__ = [
    "Bus", "BusStats", "Priority", "SlaveHandle", "SlaveStats", "Transaction",
    "TransactionObserver",
]
