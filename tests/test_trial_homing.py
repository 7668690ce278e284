"""`drivebus drive try` homes by every method a description names, each on the home switch
its CiA 402 method expects (judged by the trial's twin)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from drivebus.drives.description import load_description

ROOT = Path(__file__).resolve().parents[1]


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    """Run ``drivebus ARGS`` as a user does."""
    return subprocess.run([sys.executable, "-m", "drivebus.cli", *args], capture_output=True,
                          text=True, timeout=300, check=False, cwd=ROOT)


async def test_a_trial_homes_by_every_method_the_description_names() -> None:
    """`drive try` homes by each method, not the first only (before: the Kinco FD's
    methods 18-22, 24 and 28 were never tried, and 21/22 could not have homed: the CiA
    402 twin's home switch was always a positive cam). Each runs on the switch it
    expects; a method the profile refuses is named with its reason."""
    from drivebus.sim.trial import try_description

    d = load_description(ROOT / "configs" / "drives" / "kinco_fd.toml")
    steps = await try_description(d)
    (home,) = [s for s in steps if s.name == "home"]
    assert home.result == "pass", home
    assert d.homing is not None
    for name in d.homing.methods:
        assert f"{name}: homed" in home.detail, (name, home.detail)
    nt86 = cli("drive", "try", "NT86").stdout
    assert "hard_stop_positive: refused (" in nt86 and "closed-loop" in nt86, nt86
