"""What the service tests share: a real uvicorn server on loopback over the demo machine,
token files, and bounded waits on the simulated twins."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path

import anyio
import httpx

from drivebus.service import Service, TokenStore, open_service

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "configs" / "demo.toml"

TOKENS = {
    "alice": ("command", "alice-token-0123456789abcdef"),
    "bob": ("command", "bob-token-0123456789abcdef00"),
    "viewer": ("read", "viewer-token-0123456789abcdef"),
}


def token_file(tmp: Path) -> Path:
    """A token file with two command clients (alice, bob) and a read-only one (viewer)."""
    p = tmp / "tokens.txt"
    p.write_text("# name scope token\n" + "".join(
        f"{name} {scope} {token}\n" for name, (scope, token) in TOKENS.items()))
    p.chmod(0o600)
    return p


def auth(name: str) -> dict[str, str]:
    """The Authorization header of client ``name``."""
    return {"Authorization": f"Bearer {TOKENS[name][1]}"}


@asynccontextmanager
async def running(
    *, tokens: TokenStore | None = None, config: Path = DEMO, stats_period: float = 0.5
) -> AsyncIterator[tuple[Service, httpx.AsyncClient]]:
    """The service on 127.0.0.1 (a free port) and an HTTP client for it."""
    async with (
        open_service(config, host="127.0.0.1", port=0, tokens=tokens,
                     stats_period=stats_period) as svc,
        # plain HTTP on loopback: no TLS context (loading the CA bundle takes ~30 ms of
        # CPU in one event-loop step, which the loop-step guard would see)
        httpx.AsyncClient(base_url=svc.url or "", timeout=30, verify=False) as client,
    ):
        yield svc, client


async def until(svc: Service, check: Callable[[], bool], *, limit: float = 20.0,
                what: str = "") -> None:
    """Wait until ``check()`` holds, looking again at every axis poll (the session's
    events); ``limit`` seconds is a hang guard, not a figure."""
    with svc.session.events.subscribe({"axes"}) as polls, anyio.fail_after(limit):
        while not check():
            await polls.get()
    assert check(), what


async def moving(svc: Service, axis: str) -> None:
    """Wait until the twin of ``axis`` moves."""
    twin = svc.session.machine.sim_drives[axis]
    await until(svc, twin.is_moving, what=f"{axis} never moved")


async def at_rest(svc: Service, *axes: str, limit: float = 20.0) -> None:
    """Wait until the twins of ``axes`` (all if none) are at rest."""
    twins = svc.session.machine.sim_drives
    names = axes or tuple(twins)
    await until(svc, lambda: not any(twins[n].is_moving() for n in names), limit=limit)
