"""``drivebus`` starts in a blink: a command imports only what it runs (issue 34, item 4).

Measured as the modules the real command imports (``python -X importtime``, which lists
every module a process imports) and the drive descriptions it parses (the registry's
``FAMILIES.loaded()`` after the command ran in-process), never as a wall time: ``drivebus
--help`` loads no simulator, service, MQTT, plotting, motion layer or description; a
register ``read`` over a pty no drive description, simulator or service; a machine names
its drives and only their descriptions are parsed. The timings themselves are in the
closing note of the issue.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

from test_cli import CLI, SINGLE, sim_server

ROOT = Path(__file__).resolve().parents[1]

NEVER_AT_START = ("drivebus.sim", "drivebus.service.api", "drivebus.service.runner",
                  "drivebus.mqtt", "drivebus.bench", "fastapi", "uvicorn", "starlette",
                  "matplotlib", "aiomqtt", "paho")
"""What no command that does not serve, simulate, bridge or plot may load."""


def imported(*args: str) -> tuple[subprocess.CompletedProcess[str], set[str]]:
    """Run ``drivebus ARGS`` under ``-X importtime``: the result and the modules it imported."""
    r = subprocess.run([sys.executable, "-X", "importtime", *CLI[1:], *args],
                       capture_output=True, text=True, timeout=60, check=False, cwd=ROOT)
    modules = set(re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s+(\S+)$", r.stderr, re.M))
    assert "drivebus.cli" in modules, r.stderr[-2000:]
    return r, modules


def loaded(modules: set[str], *prefixes: str) -> list[str]:
    """The modules among ``modules`` that are one of ``prefixes`` or inside one."""
    return sorted(m for m in modules if any(m == p or m.startswith(p + ".") for p in prefixes))


def test_help_imports_no_layer_below_the_command_line() -> None:
    r, modules = imported("--help")
    assert r.returncode == 0 and "Exit status: 0 done" in " ".join(r.stdout.split())
    assert loaded(modules, *NEVER_AT_START) == []
    assert loaded(modules, "drivebus.motion", "drivebus.drives", "drivebus.app",
                  "drivebus.bus", "drivebus.line", "drivebus.config", "drivebus.service",
                  "pydantic", "rich", "anyio") == []


def test_a_register_read_on_a_pty_imports_no_description_simulator_or_service() -> None:
    with sim_server(SINGLE) as (_, ends):
        r, modules = imported("read", ends["bus"], "1", "0", "-S", "115200 8N1")
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.splitlines() == ["[0]: 862"]  # the CL86R's model register
    assert loaded(modules, *NEVER_AT_START, "drivebus.service", "drivebus.motion.axis",
                  "drivebus.motion.machine", "drivebus.drives.description",
                  "drivebus.drives.registry", "drivebus.drives.engine", "drivebus.app.session",
                  "rich.live", "rich.progress", "tomlkit") == []


IN_PROCESS = """
import json, sys
sys.argv = ["drivebus", *sys.argv[1:]]
from drivebus.cli import main
try:
    main()
except SystemExit as exc:
    code = exc.code
from drivebus.drives.registry import FAMILIES
print(json.dumps({"code": code, "parsed": FAMILIES.loaded()}), file=sys.stderr)
"""


def test_a_machine_parses_only_the_descriptions_it_names() -> None:
    r = subprocess.run([sys.executable, "-c", IN_PROCESS, "status", str(SINGLE), "--json"],
                       capture_output=True, text=True, timeout=60, check=False, cwd=ROOT)
    seen = json.loads(r.stderr.strip().splitlines()[-1])
    assert seen["code"] == 0, r.stderr
    assert json.loads(r.stdout)[0]["drive"] == "CL86R"
    # single.toml names one CL86R; its private simulator plays it from the same description
    assert seen["parsed"] == ["CL86R"]
