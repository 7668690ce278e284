"""The package as users install it: a real wheel build, its files and its metadata."""

from __future__ import annotations

import email
import importlib.metadata
import json
import re
import subprocess
import sys
import tomllib
import zipfile
from collections.abc import Callable
from pathlib import Path

import pytest

import drivebus
from drivebus.machines import DEMO
from installs import SUPPORTED, Installed, build_wheel, find, install

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def wheel(built_once: Callable[[str, Callable[[Path], None]], Path]) -> Path:
    (found,) = built_once("wheel", build_wheel).glob("drivebus-*.whl")
    return found


def _metadata(wheel: Path) -> email.message.Message:
    with zipfile.ZipFile(wheel) as z:
        name = next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))
        return email.message_from_bytes(z.read(name))


def test_the_version_is_written_once() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert "version" not in project and "version" in project["dynamic"]
    assert importlib.metadata.version("drivebus") == drivebus.__version__


def test_wheel_carries_py_typed_and_the_license(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        assert "drivebus/py.typed" in names
        licence = [n for n in names if n.endswith(".dist-info/licenses/LICENSE")]
        assert licence, names
        text = z.read(licence[0]).decode()
    assert text.startswith("MIT License") and "the drivebus authors" in text
    assert wheel.name.startswith(f"drivebus-{drivebus.__version__}-")


def test_wheel_metadata(wheel: Path) -> None:
    meta = _metadata(wheel)
    assert meta["Version"] == drivebus.__version__
    assert meta["License-Expression"] == "MIT"
    urls = dict(u.split(", ", 1) for u in meta.get_all("Project-URL", []))
    assert {"Homepage", "Documentation", "Source", "Issues", "Changelog"} <= set(urls)
    classifiers = meta.get_all("Classifier", [])
    assert "Typing :: Typed" in classifiers
    assert "modbus" in (meta["Keywords"] or "")
    requires = meta.get_all("Requires-Dist", [])
    runtime = [r for r in requires if "extra ==" not in r]
    assert not any(r.startswith("pymodbus") for r in runtime), runtime
    assert any(r.startswith("crcmod-plus") for r in runtime), runtime  # the RTU CRC
    for extra in ("test", "bench"):
        assert any(r.startswith("pymodbus") and f'extra == "{extra}"' in r for r in requires)
    assert any(r.startswith("mkdocstrings-python") and 'extra == "docs"' in r for r in requires)


def test_drivebus_imports_no_pymodbus() -> None:
    code = (
        "import sys; sys.modules['pymodbus'] = None  # as if it were not installed\n"
        "import drivebus, drivebus.line.rtu, drivebus.sim, drivebus.cli, drivebus.bench\n"
        "print(drivebus.line.rtu.crc16(bytes.fromhex('0207')).hex())\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert done.stdout.strip() == "4112"


def test_wheel_carries_every_file_of_the_package(wheel: Path) -> None:
    """Each file under src/drivebus that is not Python (the demo machine, the drive
    descriptions, the dashboard's assets and their licences, py.typed) is in the wheel:
    a command finds at run time only what ships."""
    package = ROOT / "src" / "drivebus"
    data = {p.relative_to(package.parent).as_posix() for p in package.rglob("*")
            if p.is_file() and p.suffix not in (".py", ".pyc")}
    assert "drivebus/machines/demo.toml" in data
    assert "drivebus/service/static/index.html" in data
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
    assert data - names == set()
    modules = {p.relative_to(package.parent).as_posix() for p in package.rglob("*.py")}
    assert modules - names == set()


def test_the_checkout_demo_machine_is_the_packaged_file() -> None:
    """configs/demo.toml (the README's and the examples' machine) is a link to the file
    that ships, not a copy that could drift from it."""
    checkout = ROOT / "configs" / "demo.toml"
    assert checkout.is_symlink() and checkout.resolve() == DEMO
    assert DEMO.is_relative_to(ROOT / "src" / "drivebus")


@pytest.mark.pythons
@pytest.mark.parametrize("version", SUPPORTED)
def test_the_installed_wheel_runs_from_another_folder(
    version: str, wheel: Path, tmp_path: Path
) -> None:
    """`pip install drivebus` into a fresh venv of each supported Python, then from a
    folder that is not the checkout: the version, the demo on the packaged demo machine,
    a copy of that machine written out and checked, and the package's own files found in
    the venv (the dashboard's assets, the built-in descriptions)."""
    python = find(version)
    if python is None:
        pytest.skip(f"no Python {version} on this machine (tests/pythons.py says where it "
                    "looks); pyproject.toml's classifiers promise it")
    work = tmp_path / "work"
    work.mkdir()
    env = Installed(install(python, wheel, tmp_path / "venv"), work)
    assert env.ok("drivebus", "--version").strip() == f"drivebus {drivebus.__version__}"
    where = Path(env.ok("drivebus", "demo", "--where").strip())
    assert where.is_relative_to(env.bin.parent) and where.name == "demo.toml", where
    assert where.read_bytes() == DEMO.read_bytes()
    demo = env.run("drivebus", "demo", timeout=240)
    assert "machine demo: 5 axes on 2 lines (simulated)" in demo.stdout, demo
    assert "summary: 4 coordinated/point moves" in demo.stdout and "ErrorStop" not in demo.stdout
    # Its exit status is 1 only for gap violations the simulated wire saw: on a loaded
    # machine a stall of the demo's process can make one (test_cli.test_demo_completes,
    # a serial test, holds it to none).
    violations = int(re.findall(r"gap violations (\d+)", demo.stdout)[-1])
    assert demo.returncode == (1 if violations else 0), demo
    assert "wrote mine.toml" in env.ok("drivebus", "demo", "--write", "mine.toml")
    assert (work / "mine.toml").read_bytes() == DEMO.read_bytes()
    again = env.run("drivebus", "demo", "--write", "mine.toml")
    assert again.returncode == 2 and "mine.toml exists" in again.stderr, again
    env.ok("drivebus", "check", "mine.toml")
    found = env.ok("python", "-c", (
        "import drivebus, json, sys\n"
        "from drivebus.drives.registry import FAMILIES\n"
        "from drivebus.service.api import STATIC\n"
        "print(sys.version_info[:2] == tuple(map(int, sys.argv[1].split('.'))))\n"
        "print(drivebus.__file__)\n"
        "print((STATIC / 'index.html').is_file(), (STATIC / 'vendor' / 'uplot').is_dir())\n"
        "print(json.dumps(sorted(FAMILIES)))\n"
    ), version)
    same_version, module, assets, families = found.splitlines()
    assert same_version == "True", found
    assert Path(module).is_relative_to(env.bin.parent) and not Path(module).is_relative_to(ROOT)
    assert assets == "True True", found
    assert {"NT86", "BHSS", "CL86R", "EPR60"} <= set(json.loads(families)), found
