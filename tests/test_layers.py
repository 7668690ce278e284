"""The layers hold: ``import drivebus`` loads no simulator module, and the layer contracts
in pyproject.toml (import-linter) pass."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_importing_drivebus_loads_no_simulator_module() -> None:
    code = (
        "import sys, drivebus, drivebus.app\n"
        "print(sorted(m for m in sys.modules if m.startswith('drivebus.sim')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=60)
    assert out.stdout.strip() == "[]", out.stdout


def test_opening_a_simulated_machine_loads_the_simulator_through_its_provider() -> None:
    code = (
        "import sys, anyio\n"
        "from drivebus import open_machine\n"
        "async def main():\n"
        "    async with open_machine('configs/single.toml') as m:\n"
        "        print(type(next(iter(m.sim_drives.values()))).__module__)\n"
        "anyio.run(main)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=60, cwd=ROOT)
    assert out.stdout.strip().startswith("drivebus.sim."), out.stdout  # a coded or a described twin


def test_the_layer_contracts_are_kept() -> None:
    lint = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    assert lint is not None, "import-linter is a test dependency"
    out = subprocess.run([lint], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "broken" in out.stdout and " 0 broken" in out.stdout
