"""The HTTP routes of motion programs: taught positions, speed override, digital I/O.

Thin mappings onto the session (``MachineSession.start_position_move``, ``teach``,
``set_override``, ``set_output``); included by ``create_app``.
"""

# No ``from __future__ import annotations`` here: FastAPI reads the annotations at runtime.

from typing import Annotated, Any

from fastapi import APIRouter, Response
from pydantic import BaseModel, ConfigDict, Field

from drivebus.motion.handle import MAX_OVERRIDE
from drivebus.service.deps import ERRORS, Commander, Reader, Session, accepted

__all__ = ["OutputRequest", "OverrideRequest", "PositionMoveRequest", "TeachRequest",
           "router"]

Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)


class OverrideRequest(_Body):
    """A speed override: ``factor`` times the speeds asked (0 < factor <= 2)."""

    factor: Annotated[float, Field(gt=0, le=MAX_OVERRIDE, allow_inf_nan=False)]


class OutputRequest(_Body):
    """Switch an output on (true) or off."""

    state: bool


class PositionMoveRequest(_Body):
    """Move a taught position's axes there: along the straight line at ``speed`` (the
    axes' unit/s) or in ``duration`` seconds (default: the axes' own speeds)."""

    speed: Positive | None = None
    duration: Positive | None = None


class TeachRequest(_Body):
    """The axes to teach (default: the position's, or every axis that can move)."""

    axes: list[str] | None = None


router = APIRouter(prefix="/api", responses=ERRORS)


@router.get("/positions", tags=["positions"])
async def get_positions(session: Session, _: Reader) -> dict[str, dict[str, float]]:
    """The taught positions: name -> axis -> position."""
    return session.machine.positions


@router.post("/positions/{name}/move", status_code=202, tags=["positions"])
async def move_to_position(name: str, session: Session, who: Commander, response: Response,
                           body: PositionMoveRequest | None = None) -> dict[str, Any]:
    """Start a move of the position's axes there, together; ``202`` once accepted."""
    body = body or PositionMoveRequest()
    rec = await session.start_position_move(name, speed=body.speed, duration=body.duration,
                                            client=who.name)
    accepted(response, rec.id)
    return rec.as_dict()


@router.post("/positions/{name}/teach", tags=["positions"])
async def teach(name: str, session: Session, who: Commander,
                body: TeachRequest | None = None) -> dict[str, Any]:
    """Store the axes' present positions as ``name`` (written to the machine's file)."""
    stored = await session.teach(name, None if body is None else body.axes, client=who.name)
    path = session.machine.taught.path
    return {"position": name, "axes": stored, "file": None if path is None else str(path)}


@router.get("/override", tags=["override"])
async def get_override(session: Session, _: Reader) -> dict[str, Any]:
    """The machine's speed override and each axis's (its own times the machine's)."""
    m = session.machine
    return {"machine": m.override,
            "axes": {n: {"own": a.override, "applied": a.effective_override}
                     for n, a in m.axes.items()}}


@router.put("/override", tags=["override"])
async def set_machine_override(body: OverrideRequest, session: Session, who: Commander
                               ) -> dict[str, Any]:
    """Set the machine's speed override (moves under way change speed where their drives
    can); lowering it needs no lease."""
    return {"machine": session.set_override(body.factor, client=who.name)}


@router.put("/axes/{name}/override", tags=["override"])
async def set_axis_override(name: str, body: OverrideRequest, session: Session,
                            who: Commander) -> dict[str, Any]:
    """Set one axis's own speed override (times the machine's)."""
    applied = session.set_override(body.factor, axis=name, client=who.name)
    return {"axis": name, "own": body.factor, "applied": applied}


@router.get("/axes/{name}/io", tags=["io"])
async def get_io(name: str, session: Session, _: Reader) -> dict[str, Any]:
    """The drive's inputs and outputs as last polled, and what each terminal is set to
    do (read from the drive)."""
    ax = session.axis(name)
    points = await ax.io_points()
    return {"inputs": ax.inputs, "outputs": ax.outputs,
            "terminals": [{"name": p.name, "output": p.output, "function": p.function,
                           "settable": p.settable} for p in points]}


@router.put("/axes/{name}/outputs/{output}", tags=["io"])
async def set_output(name: str, output: str, body: OutputRequest, session: Session,
                     who: Commander) -> dict[str, Any]:
    """Switch an output where the drive lets Modbus drive it (``501`` NotSupported
    naming the drive otherwise); returns once a status shows it."""
    await session.set_output(name, output, body.state, client=who.name)
    return {"axis": name, "outputs": session.axis(name).outputs}
