"""Who owns a machine, and the commands through a running ``drivebus serve``.

A machine file's lines have one owner: a ``drivebus serve`` that runs it (then every
command talks to it: ``remote_status``, ``remote_motion``, ...) or this process (then a
``sim://`` line reaches a running ``drivebus sim`` or starts a private simulator, which
``announce_sim_lines`` says). ``service_owner`` decides.
"""

from __future__ import annotations

import functools
import json
import logging
import math
import sys
import time
from collections.abc import Awaitable, Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import anyio
import anyio.to_thread

from drivebus import errors
from drivebus.cli.terminal import Out, fmt_number
from drivebus.errors import ArgumentError, ConfigError, DrivebusError
from drivebus.text import quantity

if TYPE_CHECKING:
    from drivebus.service.client import ServiceClient

__all__ = [
    "announce_sim_lines",
    "call",
    "command_line_client",
    "follow_motion",
    "motion_error",
    "remote_jog",
    "remote_monitor",
    "remote_motion",
    "remote_status",
    "remote_stop",
    "service_owner",
]


# -- through a running drivebus serve (the line's one owner) ---------------------------------------


def announce_sim_lines(config: Path) -> None:
    """Say on stderr, for each ``sim://`` line of ``config``, whether opening the machine
    here reaches a running ``drivebus sim`` (always) or starts a private simulator (on a
    terminal; logged at INFO otherwise, which ``-v`` shows)."""
    from drivebus.config import load_config

    try:
        cfg = load_config(config)
    except ConfigError:
        return  # the command itself says what is wrong with the file
    for ln in cfg.lines.values():
        if not ln.simulated:
            continue
        from drivebus.sim.serve import published

        found = published(ln.sim_name)
        where = ln.port or ln.host
        if found is not None:
            print(f"note: {where}: reaching the running drivebus sim on {found.where}",
                  file=sys.stderr, flush=True)
            continue
        note = (f"{where}: no drivebus sim serves it: starting a private simulator (its "
                f"drives start afresh; `drivebus sim CONFIG` keeps them between commands)")
        if sys.stderr.isatty():  # at a terminal; scripts and pipes see it with -v
            print(f"note: {note}", file=sys.stderr, flush=True)
        else:
            logging.getLogger("drivebus.sim").info(note)


def service_owner(
    config: Path, server: str | None, token: str | None, local: bool
) -> ServiceClient | None:
    """The ``drivebus serve`` that owns ``config``'s machine (``--server``, or found
    through the file), as a client; None to open the machine here."""
    from drivebus.service.client import find_service

    url = None if local else server or find_service(config)
    if url is None:
        announce_sim_lines(config)
        return None
    if server is None:
        print(f"note: {config} is served by a running drivebus serve at {url}: talking to "
              f"it (--local opens the machine here)", file=sys.stderr, flush=True)
    return command_line_client(url, token)


def command_line_client(url: str, token: str | None) -> ServiceClient:
    """A client of the ``drivebus serve`` at ``url`` for the command line: a refusal for
    want of a token (401) or of its scope (403) names the option and the variable that
    give one, not an HTTP header."""
    from drivebus.service.client import ServiceClient

    class CommandLineClient(ServiceClient):
        def refused(self, status: int, name: str, detail: str) -> DrivebusError:
            where = f"the drivebus service at {self.url}"
            if status == 403:
                return DrivebusError(
                    f"{where} refused the request: {detail}; give a token of scope 'command' "
                    f"with --token TOKEN or DRIVEBUS_TOKEN=TOKEN")
            if status == 401:
                why = ("does not know the token given" if self.token else
                       "needs a token and none was given")
                return DrivebusError(
                    f"{where} {why}; give one of its token file with --token TOKEN or in the "
                    f"environment, DRIVEBUS_TOKEN=TOKEN (a line 'NAME read|command TOKEN' of "
                    f"the file its --token-file names)")
            return super().refused(status, name, detail)

    return CommandLineClient(url, token=token)


async def call(fn: Callable[..., Any], *args: Any) -> Any:
    """A blocking client request, off the event loop."""
    return await anyio.to_thread.run_sync(functools.partial(fn, *args))


def _remote_line(a: dict[str, Any]) -> str:
    flags = [k for k in ("enabled", "moving", "homed", "limit_negative", "limit_positive")
             if a.get(k)]
    extra = ""
    if a.get("alarm"):
        extra = f" alarm={a.get('alarm_code')} {a.get('alarm_text', '')}".rstrip()
    elif a.get("error"):
        extra = f" error={a['error'].get('message')!r}"
    unit = str(a.get("units") or "")
    return (f"{a['name']}: {a['drive']} line={a['line']} address={a['address']} "
            f"state={a['state']} position={quantity(a.get('position'), unit)} "
            f"velocity={quantity(a.get('velocity'), unit + '/s')} "
            f"flags={','.join(flags) or '-'}{extra}")


async def remote_status(out: Out, client: ServiceClient, axes: Sequence[str], as_json: bool
                        ) -> int:
    """``status`` through the service: every axis (or the named ones) as it polls them."""
    machine = await call(client.machine)
    names = list(axes) or [a["name"] for a in machine["axes"]]
    records = [await call(client.axis, n) for n in names]
    if as_json:
        print(json.dumps([{"axis": r["name"], **r} for r in records], indent=2), flush=True)
    else:
        for r in records:
            out.line(_remote_line(r))
    faults = [r for r in records if r["state"] == "Offline" or r.get("alarm")]
    return 1 if faults else 0


async def follow_motion(
    client: ServiceClient, path: str, body: object = None,
    tick: Callable[[dict[str, Any]], Awaitable[None]] | None = None,
    started: Callable[[], None] | None = None,
) -> dict[str, Any]:
    """Start a motion on the service (``POST path``) and follow it to its end: its last
    record (``tick`` gets each running one, the first included; ``started`` is called
    once the service took it). Cancelled (Ctrl-C), the motion is cancelled, its axes
    stopped, before this re-raises."""
    record: dict[str, Any] = await _refusal_as_argument(call(client.start, path, body))
    if started is not None:
        started()
    try:
        while record.get("state") == "running":
            if tick is not None:
                await tick(record)
            await anyio.sleep(0.05)
            record = await call(client.request, "GET", f"/motions/{record['id']}")
    except BaseException:
        with anyio.CancelScope(shield=True):
            await call(client.cancel, record["id"])
        raise
    return record


async def _refusal_as_argument(request: Awaitable[Any]) -> Any:
    """``request``'s reply; the service refusing it for a limit or what the drive cannot
    do (nothing was started) is an ``ArgumentError``, exit status 2, as when the machine
    is opened here."""
    try:
        return await request
    except (errors.LimitViolation, errors.NotSupported) as exc:
        if isinstance(exc, errors.ConfigError):
            raise
        raise ArgumentError(str(exc)) from None


def motion_error(record: dict[str, Any], what: str) -> DrivebusError:
    """The typed error a motion that did not complete (aborted, failed) ended with."""
    err = record.get("error") or {}
    kind = getattr(errors, str(err.get("type")), DrivebusError)
    if not (isinstance(kind, type) and issubclass(kind, DrivebusError)):
        kind = DrivebusError
    return kind(str(err.get("message", f"the {what} ended {record['state']}")))


async def remote_motion(out: Out, client: ServiceClient, axis: str, what: str, path: str,
                        body: object = None) -> int:
    """Start a motion on the service and wait for it; cancelled (Ctrl-C), cancel it.
    ``axis`` is the axis shown while it runs ("": the motion's own axes, not shown)."""
    started = shown = time.monotonic()
    names = [axis] if axis else []
    accepted: list[bool] = []  # the service took the motion (a refusal started nothing)

    async def tick(record: dict[str, Any]) -> None:
        nonlocal shown
        if not names:
            names.extend(record.get("axes") or [])
        if time.monotonic() - shown >= 0.2 and len(names) == 1:
            shown = time.monotonic()
            a = await call(client.axis, names[0])
            out.line(f"{names[0]}: position={fmt_number(a.get('position'))} "
                     f"velocity={fmt_number(a.get('velocity'))} state={a['state']}")

    try:
        record = await follow_motion(client, path, body, tick,
                                     started=lambda: accepted.append(True))
    except BaseException:
        with anyio.CancelScope(shield=True):
            for name in names if accepted else []:
                a = await call(client.axis, name)
                out.line(f"{name}: {what} stopped after {time.monotonic() - started:.2f} s, "
                         f"position={fmt_number(a.get('position'))} state={a['state']}")
        raise
    names = names or list(record.get("axes") or [])
    seen = {name: await call(client.axis, name) for name in names}
    a = next(iter(seen.values()))
    op = {"axis": ",".join(names), "what": what, "done": record["state"] == "done",
          "seconds": round(time.monotonic() - started, 4), "position": a.get("position"),
          "state": a["state"], "motion": record}
    if record["state"] != "done":
        raise motion_error(record, what)
    for name, a in seen.items():
        out.line(f"{name}: {what} done in {op['seconds']:.2f} s, "
                 f"position={fmt_number(a.get('position'))} state={a['state']}")
    out.result(op)
    return 0


async def remote_jog(out: Out, client: ServiceClient, axis: str, speed: float,
                     seconds: float | None) -> int:
    """Jog through the service, fed every 0.2 s (a 0.5 s watchdog); stop at the end."""
    started = time.monotonic()
    refused = False
    try:
        try:
            await _refusal_as_argument(
                call(client.command, axis, "jog", {"speed": speed, "ttl": 0.5}))
        except DrivebusError as exc:
            # the service answered no (a limit, a drive that cannot, the wrong state): the
            # jog started nothing, so no stop either, which would stop a motion someone
            # else runs on the axis; unreachable, it may have started: stop it
            refused = not isinstance(exc, errors.ServiceUnreachable)
            raise
        with anyio.move_on_after(seconds if seconds else math.inf):
            while True:
                await anyio.sleep(0.2)
                await call(client.command, axis, "jog", {"speed": speed, "ttl": 0.5})
    finally:
        if not refused:
            await _stop_jog(out, client, axis, speed, started)
    return 0


async def _stop_jog(out: Out, client: ServiceClient, axis: str, speed: float,
                    started: float) -> None:
    """The end of a jog through the service: its stop, and where it left the axis."""
    with anyio.CancelScope(shield=True):
        await call(client.command, axis, "stop")
        a = await call(client.axis, axis)
        out.line(f"{axis}: jog at {speed:g}/s ended after "
                 f"{time.monotonic() - started:.2f} s, "
                 f"position={fmt_number(a.get('position'))} state={a['state']}")
        out.result({"axis": axis, "what": f"jog at {speed:g}", "done": True,
                    "position": a.get("position"), "state": a["state"]})


async def remote_stop(out: Out, client: ServiceClient, axes: Sequence[str]) -> int:
    """``stop`` through the service."""
    machine = await call(client.machine)
    names = list(axes) or [a["name"] for a in machine["axes"]]
    records = []
    for n in names:
        await call(client.command, n, "stop")
        a = await call(client.axis, n)
        out.line(f"{n}: at standstill at position={fmt_number(a.get('position'))} "
                 f"state={a['state']}")
        records.append({"axis": n, "position": a.get("position"), "state": a["state"]})
    out.result(records)
    return 0


async def remote_monitor(out: Out, client: ServiceClient, interval: float,
                         count: int | None) -> int:
    """``monitor`` through the service: its axes every ``interval`` s."""
    n = 0
    while count is None or n < count:
        machine = await call(client.machine)
        records = [await call(client.axis, a["name"]) for a in machine["axes"]]
        if out.as_json:
            out.result({"time": time.time(), "axes": records, "lines": machine["lines"]},
                       indent=None)
        else:
            stamp = time.strftime("%H:%M:%S")
            for r in records:
                out.line(f"{stamp} {_remote_line(r)}")
        n += 1
        if count is None or n < count:
            await anyio.sleep(interval)
    return 0
