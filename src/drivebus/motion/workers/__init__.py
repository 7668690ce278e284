"""Worker processes that serve a machine's lines when one process is not enough.

A machine file's ``workers = N`` (or ``"auto"``) places its lines in N worker processes,
each running its lines' schedulers and timing; the axes, the application layer, the
service and MQTT stay in the machine's process and see each line through a ``RemoteBus``
with the interface of ``Bus``.
"""

from drivebus.motion.workers.remote import (
    LineSpec,
    RemoteBus,
    RemoteLine,
    WorkerPool,
    auto_workers,
    placement,
)

__all__ = ["LineSpec", "RemoteBus", "RemoteLine", "WorkerPool", "auto_workers", "placement"]
