"""A client of `drivebus serve`: a move and an e-stop through the service's HTTP API, and
the live axis states from its WebSocket.

Start the service first (on the demo machine, in another shell):

    drivebus serve configs/demo.toml            # http://127.0.0.1:8000

then run this (httpx is the HTTP client: `pip install httpx`; give the token with
DRIVEBUS_TOKEN when the service has a --token-file):

    .venv/bin/python examples/http_client.py [http://127.0.0.1:8000]
"""

from __future__ import annotations

import json
import os
import sys
import time

import httpx
from websockets.sync.client import connect


def wait_done(api: httpx.Client, motion: str) -> dict[str, object]:
    """Poll a motion until it is no longer running."""
    for _ in range(600):
        rec = api.get(f"/api/motions/{motion}").json()
        if rec["state"] != "running":
            return dict(rec)
        time.sleep(0.05)
    raise TimeoutError(f"motion {motion} still running")


def wait_state(api: httpx.Client, axis: str, state: str) -> None:
    """Poll an axis until it is in ``state``."""
    for _ in range(600):
        if api.get(f"/api/axes/{axis}").json()["state"] == state:
            return
        time.sleep(0.02)
    raise TimeoutError(f"axis {axis} never reached {state}")


def main(url: str) -> None:
    token = os.environ.get("DRIVEBUS_TOKEN")
    headers = {"X-Drivebus-Client": "example"}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    with httpx.Client(base_url=url, headers=headers, timeout=30) as api:
        machine = api.get("/api/machine").raise_for_status().json()
        print(f"machine {machine['name']}: "
              + ", ".join(f"{a['name']}={a['state']}" for a in machine["axes"]))

        # every axis as it is polled: the WebSocket's one fixed message shape
        ws_url = url.replace("http", "ws", 1) + "/api/ws"
        with connect(ws_url, additional_headers=headers) as ws:
            json.loads(ws.recv())  # hello
            ws.send(json.dumps({"subscribe": ["axes"]}))
            json.loads(ws.recv())  # subscribed
            seen: set[str] = set()
            while len(seen) < len(machine["axes"]):
                msg = json.loads(ws.recv())
                if msg["type"] == "axis" and msg["axis"] not in seen:
                    seen.add(msg["axis"])
                    print(f"ws: {msg['axis']} {msg['state']} at {msg['position']}")

        # a move: 202 with the motion's id, then its state until done
        r = api.post("/api/axes/x/move", json={"target": 120.0, "speed": 100.0})
        r.raise_for_status()
        print(f"move accepted: {r.json()['id']} ({r.headers['location']})")
        rec = wait_done(api, r.json()["id"])
        x = api.get("/api/axes/x").json()
        print(f"move {rec['id']} {rec['state']}: x at {x['position']:.2f}")

        # an error is a typed problem (RFC 9457)
        r = api.post("/api/axes/x/move", json={"target": 5000.0})
        problem = r.json()
        print(f"refused: {r.status_code} {problem['title']}: {problem['detail']}")

        # the e-stop: two axes moving, one call halts everything
        long_move = api.post("/api/axes/x/move", json={"target": 390.0, "speed": 50.0}).json()
        api.post("/api/axes/r/move", json={"target": 700.0}).raise_for_status()
        wait_state(api, "x", "DiscreteMotion")
        outcome = api.post("/api/estop").raise_for_status().json()["axes"]
        print("estop: " + ", ".join(f"{n}={'at rest' if e is None else e['type']}"
                                    for n, e in outcome.items()))
        print(f"the long move ended {wait_done(api, long_move['id'])['state']}")
        states = {a["name"]: a["state"] for a in api.get("/api/axes").json()}
        print("after the estop: " + ", ".join(f"{n}={s}" for n, s in states.items()))
        moving = [n for n, s in states.items() if s in ("DiscreteMotion", "ContinuousMotion",
                                                         "Homing", "Stopping")]
        print("http client done: " + ("every axis at rest" if not moving
                                      else f"still moving: {', '.join(moving)}"))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "http://127.0.0.1:8000")
