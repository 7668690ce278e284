"""The package as users install it: a real wheel build, its files and its metadata."""

from __future__ import annotations

import email
import importlib.metadata
import subprocess
import sys
import tomllib
import zipfile
from collections.abc import Callable
from pathlib import Path

import pytest

import drivebus

ROOT = Path(__file__).resolve().parent.parent


def build_wheel(out: Path) -> None:
    """A wheel built from the work tree into ``out`` by pip, as `pip install .` builds it."""
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(out), str(ROOT)],
        check=True, timeout=300, capture_output=True,
    )


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
