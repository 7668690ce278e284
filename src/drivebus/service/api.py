"""The HTTP API over one ``MachineSession``: routes, authentication, the dashboard's files.

``create_app(session, tokens)`` builds the FastAPI application; ``drivebus.service.runner``
serves it with uvicorn. Every route is a thin mapping onto the session: the session
checks arguments, states and the lease and raises typed errors, which
``drivebus.service.problems`` turns into problem+json answers.
"""

# No ``from __future__ import annotations`` here: FastAPI reads the annotations at runtime.

import mimetypes
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import anyio
import anyio.to_thread
from fastapi import APIRouter, FastAPI, Request, Response
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, StreamingResponse
from fastapi.staticfiles import StaticFiles

from drivebus.app import MachineSession
from drivebus.service import metrics, problems
from drivebus.service.auth import TokenStore
from drivebus.service.bodies import BodyLimits
from drivebus.service.deps import (
    ERRORS,
    Commander,
    Reader,
    ServiceState,
    Session,
    accepted,
    reader,
    service_state,
)
from drivebus.service.models import (
    GroupMoveRequest,
    JogRequest,
    LeaseRequest,
    MoveRequest,
    NoParameters,
    ParametersRequest,
    ReadRequest,
    RecordingRequest,
    StopRequest,
    WriteRequest,
)

__all__ = ["STATIC", "ServiceState", "create_app"]

STATIC = Path(__file__).resolve().parent / "static"
"""The dashboard's files (shipped as package data)."""

router = APIRouter(prefix="/api", responses=ERRORS)


def _lease(session: MachineSession) -> dict[str, Any]:
    lease = session.lease
    if lease is None:
        return {"holder": None, "remaining": None}
    return {"holder": lease.holder, "remaining": round(lease.remaining, 3)}


# -- looking ----------------------------------------------------------------------------------


@router.get("/machine", tags=["machine"])
async def get_machine(session: Session, _: Reader) -> dict[str, Any]:
    """The machine: its name, lines (kind, settings, utilisation, counters), axes
    (drive, state, position, ...) and who holds the command lease."""
    data = session.snapshot().as_dict()
    data["lease"] = _lease(session)
    return data


@router.get("/client", tags=["machine"])
async def get_client(request: Request, who: Reader) -> dict[str, Any]:
    """Who the caller is to this service: its name and scope, and whether tokens are on."""
    state = service_state(request)
    return {"client": who.name, "scope": who.scope, "tokens": state.tokens.enabled,
            "machine": state.session.name}


@router.get("/axes", tags=["axes"])
async def get_axes(session: Session, _: Reader) -> list[dict[str, Any]]:
    """Every axis as last polled."""
    return [session.axis_snapshot(n).as_dict() for n in session.machine.axes]


@router.get("/axes/{name}", tags=["axes"])
async def get_axis(name: str, session: Session, _: Reader) -> dict[str, Any]:
    """One axis: state, position, velocity, enabled, homed, alarm code and text, limit
    switches, soft limits, units."""
    return session.axis_snapshot(name).as_dict()


@router.get("/lines/{line}", tags=["lines"])
async def get_line(line: str, session: Session, _: Reader) -> dict[str, Any]:
    """One line: kind, endpoint, settings, utilisation and per-slave counters."""
    return session.line_snapshot(line).as_dict()


# -- motions with an id -----------------------------------------------------------------------


@router.post("/axes/{name}/move", status_code=202, tags=["motions"])
async def move(
    name: str, body: MoveRequest, session: Session, who: Commander, response: Response
) -> dict[str, Any]:
    """Start a move; ``202`` once the axis accepted it, with ``Location`` of its motion.
    ``buffer`` (default ``aborting``) says what it does to a motion under way: take it
    over on the fly where the drive can (the motion under way ends ``aborted``; ``409``
    where the drive cannot), or queue behind it (``buffered``, ``blending``)."""
    rec = await session.start_move(name, target=body.target, by=body.by, speed=body.speed,
                                   accel=body.accel, decel=body.decel, buffer=body.buffer,
                                   client=who.name)
    accepted(response, rec.id)
    return rec.as_dict()


@router.post("/axes/{name}/home", status_code=202, tags=["motions"])
async def home(name: str, session: Session, who: Commander, response: Response,
               _: NoParameters | None = None) -> dict[str, Any]:
    """Start the axis's homing procedure (its machine file's method and speeds: a body
    may only be ``{}``); ``202`` once accepted."""
    rec = await session.start_home(name, client=who.name)
    accepted(response, rec.id)
    return rec.as_dict()


@router.post("/machine/group-move", status_code=202, tags=["motions"])
async def group_move(body: GroupMoveRequest, session: Session, who: Commander,
                     response: Response) -> dict[str, Any]:
    """Start a coordinated move: the axes arrive at their targets together."""
    rec = await session.start_group_move(body.targets, client=who.name)
    accepted(response, rec.id)
    return rec.as_dict()


@router.get("/motions", tags=["motions"])
async def get_motions(session: Session, _: Reader) -> list[dict[str, Any]]:
    """The motions still known, oldest first."""
    return [r.as_dict() for r in session.motions()]


@router.get("/motions/{motion_id}", tags=["motions"])
async def get_motion(motion_id: str, session: Session, _: Reader) -> dict[str, Any]:
    """A motion: ``running``, ``done``, ``aborted`` or ``failed`` (with the typed error)."""
    return session.motion(motion_id).as_dict()


@router.delete("/motions/{motion_id}", tags=["motions"])
async def cancel_motion(motion_id: str, session: Session, who: Commander) -> dict[str, Any]:
    """Cancel a motion: its axes stop; returns once they are at rest."""
    return (await session.cancel_motion(motion_id, client=who.name)).as_dict()


# -- direct commands --------------------------------------------------------------------------


@router.post("/axes/{name}/stop", tags=["axes"])
async def stop(name: str, session: Session, who: Commander,
               body: StopRequest | None = None) -> dict[str, Any]:
    """Decelerating stop; returns at rest."""
    await session.stop(name, decel=None if body is None else body.decel, client=who.name)
    return session.axis_snapshot(name).as_dict()


@router.post("/axes/{name}/halt", tags=["axes"])
async def halt(name: str, session: Session, who: Commander) -> dict[str, Any]:
    """Emergency stop of one axis (never refused by the lease); returns at rest."""
    await session.halt(name, client=who.name)
    return session.axis_snapshot(name).as_dict()


@router.post("/axes/{name}/enable", tags=["axes"])
async def enable(name: str, session: Session, who: Commander,
                 _: NoParameters | None = None) -> dict[str, Any]:
    """Energise the motor."""
    await session.enable(name, client=who.name)
    return session.axis_snapshot(name).as_dict()


@router.post("/axes/{name}/disable", tags=["axes"])
async def disable(name: str, session: Session, who: Commander,
                  _: NoParameters | None = None) -> dict[str, Any]:
    """De-energise the motor (at rest)."""
    await session.disable(name, client=who.name)
    return session.axis_snapshot(name).as_dict()


@router.post("/axes/{name}/reset", tags=["axes"])
async def reset(name: str, session: Session, who: Commander,
                _: NoParameters | None = None) -> dict[str, Any]:
    """Leave ErrorStop (clear the drive's alarm if it has one)."""
    await session.reset(name, client=who.name)
    return session.axis_snapshot(name).as_dict()


@router.post("/axes/{name}/jog", tags=["axes"])
async def jog(name: str, body: JogRequest, session: Session, who: Commander
              ) -> dict[str, Any]:
    """Jog at ``speed`` until ``ttl`` seconds after the last such request (repeat it to
    keep jogging; speed 0 stops). The WebSocket's ``jog`` message does the same."""
    await session.jog(name, body.speed, ttl=body.ttl, accel=body.accel, decel=body.decel,
                      client=who.name)
    return {"axis": name, "speed": body.speed, "ttl": body.ttl}


@router.post("/estop", tags=["machine"])
async def estop(session: Session, _: Reader) -> dict[str, Any]:
    """Emergency-stop every axis at once. Never queued behind other requests, never
    refused by the lease, allowed to every authenticated client (read scope too);
    returns when every axis is at rest, with each axis's outcome (null: at rest)."""
    return {"axes": await session.estop()}


# -- the command lease ------------------------------------------------------------------------


@router.get("/lease", tags=["lease"])
async def get_lease(session: Session, _: Reader) -> dict[str, Any]:
    """Who holds the command lease (``holder`` null: nobody) and for how much longer."""
    return _lease(session)


@router.post("/lease", tags=["lease"])
async def take_lease(session: Session, who: Commander, body: LeaseRequest | None = None
                     ) -> dict[str, Any]:
    """Take or renew the command lease: commands from other clients get ``409 LeaseHeld``
    until it expires or is given back (the e-stop excepted)."""
    session.acquire_lease(who.name, 30.0 if body is None else body.ttl)
    return _lease(session)


@router.delete("/lease", tags=["lease"])
async def give_back_lease(session: Session, who: Commander) -> dict[str, Any]:
    """Give the lease back (nothing happens if the caller does not hold it)."""
    session.release_lease(who.name)
    return _lease(session)


# -- drive parameters -------------------------------------------------------------------------


@router.get("/axes/{name}/parameters", tags=["axes"])
async def get_parameters(name: str, session: Session, _: Reader) -> dict[str, Any]:
    """Every documented parameter of the axis's drive: value, unit, register, whether a
    save stores it (reads only: nothing is written to the drive)."""
    return (await session.read_parameters(name)).as_dict()


@router.put("/axes/{name}/parameters", tags=["axes"])
async def put_parameters(name: str, body: ParametersRequest, session: Session,
                         who: Commander) -> dict[str, Any]:
    """Write the given parameters that differ from the drive's, all range-checked before
    the first write; with ``save`` the drive stores them once at the end. Refused while
    the axis moves."""
    report = await session.load_parameters(
        name, body.values, save=body.save, dry_run=body.dry_run,
        include_comms=body.include_comms, client=who.name)
    return report.as_dict()


# -- raw registers ----------------------------------------------------------------------------


@router.post("/lines/{line}/read", tags=["lines"])
async def read_registers(line: str, body: ReadRequest, session: Session, _: Reader
                         ) -> dict[str, Any]:
    """Read holding (or input) registers of a slave on the line, between the axes' polls."""
    words = await session.read_registers(line, body.address, body.first, body.count,
                                         input=body.input)
    return {"line": line, "address": body.address, "register": body.first, "words": words}


@router.post("/lines/{line}/write", tags=["lines"])
async def write_registers(line: str, body: WriteRequest, session: Session, who: Commander
                          ) -> dict[str, Any]:
    """Write registers of a slave on the line (FC06 for one value, FC16 for more; never
    retried). Bypasses the axes: for commissioning."""
    await session.write_registers(line, body.address, body.first, body.values,
                                  client=who.name)
    return {"line": line, "address": body.address, "register": body.first,
            "written": len(body.values)}


# -- recordings -------------------------------------------------------------------------------


@router.post("/recordings", status_code=201, tags=["recordings"])
async def start_recording(session: Session, who: Reader, response: Response,
                          body: RecordingRequest | None = None) -> dict[str, Any]:
    """Start recording the axes (all, or ``axes``) and their lines: every polled sample,
    motion event and transaction, with no extra bus traffic. Any client may record."""
    rec = session.recordings.start(None if body is None else body.axes, client=who.name)
    response.headers["Location"] = f"/api/recordings/{rec.id}"
    return rec.as_dict()


@router.get("/recordings", tags=["recordings"])
async def get_recordings(session: Session, _: Reader) -> list[dict[str, Any]]:
    """The recordings kept, oldest first (running or stopped)."""
    return [r.as_dict() for r in session.recordings.all()]


@router.get("/recordings/{rec_id}", tags=["recordings"])
async def get_recording(rec_id: str, session: Session, _: Reader) -> dict[str, Any]:
    """One recording: running or not, its duration and how much it holds."""
    return session.recordings.get(rec_id).as_dict()


@router.post("/recordings/{rec_id}/stop", tags=["recordings"])
async def stop_recording(rec_id: str, session: Session, _: Reader) -> dict[str, Any]:
    """Stop a recording; what it recorded is kept."""
    return session.recordings.stop(rec_id).as_dict()


def _download(name: str) -> dict[str, str]:
    return {"Content-Disposition": f'attachment; filename="{name}"'}


DOWNLOAD_CHUNK = 1 << 20
"""Bytes a recording's download sends at a time: one event-loop step each (a long
recording's JSON lines are tens of megabytes)."""


def _in_chunks(data: bytes) -> AsyncIterator[bytes]:
    """``data`` a ``DOWNLOAD_CHUNK`` at a time, for a ``StreamingResponse``."""
    async def chunks() -> AsyncIterator[bytes]:
        for at in range(0, len(data), DOWNLOAD_CHUNK):
            yield data[at:at + DOWNLOAD_CHUNK]

    return chunks()


async def _exported(export: Callable[[], str]) -> bytes:
    """What ``export()`` makes of a recording's copy, UTF-8, made in a worker thread: a
    long recording takes seconds to write out, which on the event loop would hold up
    every stop meanwhile."""
    return await anyio.to_thread.run_sync(lambda: export().encode("utf-8"))


@router.get("/recordings/{rec_id}/report", tags=["recordings"], response_class=HTMLResponse)
async def recording_report(rec_id: str, session: Session, _: Reader) -> Response:
    """The recording as one self-contained HTML report (charts per axis and line; it
    opens with no network), as a download."""
    from drivebus.service import report

    record = session.recordings.get(rec_id)
    copy = record.recording.snapshot()  # (its rings as they are now: it may go on)
    html = await _exported(lambda: report.report_html(copy))
    return StreamingResponse(_in_chunks(html), media_type="text/html; charset=utf-8",
                             headers=_download(f"drivebus-{session.name}-{record.id}.html"))


@router.get("/recordings/{rec_id}/jsonl", tags=["recordings"])
async def recording_jsonl(rec_id: str, session: Session, _: Reader) -> Response:
    """The whole recording as JSON lines (a header with the units, then samples, events
    and transactions), as a download; ``drivebus.Recording.from_jsonl`` reads it."""
    record = session.recordings.get(rec_id)
    lines = await _exported(record.recording.snapshot().to_jsonl)
    return StreamingResponse(_in_chunks(lines), media_type="application/x-ndjson",
                             headers=_download(f"drivebus-{session.name}-{record.id}.jsonl"))


# -- the application --------------------------------------------------------------------------


_LOCAL_ONLY = ("default-src 'self'; script-src 'self' 'unsafe-inline'; style-src 'self' "
               "'unsafe-inline'; img-src 'self' data:; font-src 'self' data:; "
               "worker-src 'self' blob:; connect-src 'self'")
"""The API docs' content security policy: nothing but this service (air-gapped plants)."""


def _local_only(page: HTMLResponse) -> HTMLResponse:
    page.headers["Content-Security-Policy"] = _LOCAL_ONLY
    return page


_NOWHERE = "/.drivebus-route-once"
"""A path no route has: a request to it visits every route."""


def _route_once(app: FastAPI) -> None:
    """Route one request through ``app`` in this (worker) thread, on an event loop of its
    own, and build the OpenAPI schema and the table of media types: FastAPI builds its
    routing tables on the first request and the schema on the first ``/openapi.json``
    (35-75 ms of CPU each), Python reads the system's media types on the first static file
    served (17-33 ms), which would otherwise hold the service's event loop, and every stop
    behind it, at a client's request. The request matches nothing (404) and touches no
    machine."""

    async def call() -> None:
        async def receive() -> dict[str, Any]:
            return {"type": "http.request", "body": b"", "more_body": False}

        async def send(_: Any) -> None:
            return None

        await app({"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
                   "method": "GET", "scheme": "http", "path": _NOWHERE,
                   "raw_path": _NOWHERE.encode(), "query_string": b"", "root_path": "",
                   "headers": [], "client": ("127.0.0.1", 0), "server": ("127.0.0.1", 0)},
                  receive, send)

    anyio.run(call)
    app.openapi()  # kept by the app (openapi_schema)
    mimetypes.init()  # (the dashboard's files' media types: read on the first file served)


def create_app(session: MachineSession, tokens: TokenStore | None = None) -> FastAPI:
    """The service's ASGI application over ``session`` (no tokens: no authentication)."""
    from drivebus.service.ws import websocket_endpoint

    tokens = tokens or TokenStore()
    state = ServiceState(session, tokens)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await anyio.to_thread.run_sync(_route_once, app)
        async with anyio.create_task_group() as tg:
            await tg.start(state.fanout.run, name="drivebus service: websocket fan-out")
            yield
            tg.cancel_scope.cancel()

    app = FastAPI(
        lifespan=lifespan,
        title=f"drivebus: machine {session.name}",
        version="1",
        description="Modbus drives on shared lines: axes, motions, e-stop, leases, raw "
                    "registers; live updates on the WebSocket /api/ws.",
        docs_url=None,  # served below from the package's own copies: no CDN
        redoc_url=None,
    )
    app.state.drivebus = state
    problems.install(app)
    app.add_middleware(BodyLimits)  # size and depth: refused before FastAPI parses them
    app.include_router(router)
    root = APIRouter()
    metrics.install(root, reader)  # GET /metrics, for Prometheus
    app.include_router(root)
    from drivebus.service.programs_api import router as programs

    app.include_router(programs)  # positions, override, I/O
    app.add_api_websocket_route("/api/ws", websocket_endpoint)
    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.get("/", include_in_schema=False)
    async def dashboard() -> FileResponse:
        return FileResponse(STATIC / "index.html")

    @app.get("/favicon.ico", include_in_schema=False)
    async def favicon() -> FileResponse:
        return FileResponse(STATIC / "favicon.ico", media_type="image/x-icon")

    @app.get("/docs", include_in_schema=False)
    async def swagger_ui() -> HTMLResponse:
        return _local_only(get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json", title=f"{app.title}: API",
            swagger_js_url="/static/vendor/swagger-ui/swagger-ui-bundle.js",
            swagger_css_url="/static/vendor/swagger-ui/swagger-ui.css",
            swagger_favicon_url="/static/vendor/swagger-ui/favicon-32x32.png",
            swagger_ui_parameters={"validatorUrl": None},
        ))

    @app.get("/redoc", include_in_schema=False)
    async def redoc() -> HTMLResponse:
        # ReDoc's sidebar shows a Redocly logo from its CDN: the policy keeps it off the
        # network (the image hides itself when it does not load).
        return _local_only(get_redoc_html(
            openapi_url=app.openapi_url or "/openapi.json", title=f"{app.title}: API",
            redoc_js_url="/static/vendor/redoc/redoc.standalone.js",
            redoc_favicon_url="/static/vendor/swagger-ui/favicon-32x32.png",
            with_google_fonts=False,
        ))

    return app
