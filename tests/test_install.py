"""Real installs into throwaway venvs (slow: `make test-install`, marker ``install``).

- `pip install .` into a venv that already holds another pymodbus leaves that pymodbus
  alone, and drivebus works there (its CRC is its own).
- The tests that use pymodbus pass on the lowest and on the newest pymodbus of the
  ranges that the ``test`` and ``bench`` extras declare in pyproject.toml.
- The wheel with the ``bench``, ``plots`` and ``parquet`` extras, each used once from a
  folder outside the checkout (``make test`` runs the plain wheel on every supported
  Python: tests/test_packaging.py).

Each venv is new, pip resolves against the package index as a user's would (no
``--no-deps``), and the tests run from this work tree against the installed package.
"""

from __future__ import annotations

import json
import re
import subprocess
import tomllib
import venv
from collections.abc import Callable
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet
from packaging.version import Version

from installs import SUPPORTED, Installed, build_wheel, find, install

pytestmark = pytest.mark.install

ROOT = Path(__file__).resolve().parent.parent
INSTALL_TIMEOUT = 900
OLDER_PYMODBUS = "3.6.9"
"""A pymodbus outside every range of ours, as an automation user may already have."""

PYMODBUS_TESTS = [
    "tests/test_rtu_crc.py",
    "tests/test_codec.py",
    "tests/test_tcp_line.py",
    "tests/test_pymodbus_peer.py",
    "tests/test_bench.py",
]
BENCH_TESTS = ["tests/test_rtu_crc.py", "tests/test_bench.py"]
RUNNERS = ["pytest>=8", "pytest-asyncio>=0.23", "pytest-timeout>=2.3", "hypothesis>=6.100"]


def extra_range(extra: str) -> SpecifierSet:
    """The pymodbus specifier of ``extra`` in pyproject.toml."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    for line in project["optional-dependencies"][extra]:
        req = Requirement(line)
        if req.name == "pymodbus":
            return req.specifier
    raise AssertionError(f"extra {extra!r} has no pymodbus")


def lowest(spec: SpecifierSet) -> str:
    (low,) = [s.version for s in spec if s.operator == ">="]
    return low


class Venv:
    """A fresh venv in ``path`` with pip."""

    def __init__(self, path: Path) -> None:
        venv.create(path, with_pip=True, clear=True)
        self.python = str(path / "bin" / "python")

    def run(self, *args: str, timeout: float = INSTALL_TIMEOUT) -> str:
        done = subprocess.run(
            [self.python, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout
        )
        assert done.returncode == 0, f"{' '.join(args)}:\n{done.stdout}\n{done.stderr}"
        return done.stdout

    def pip(self, *args: str) -> str:
        return self.run("-m", "pip", "--disable-pip-version-check", *args)

    def version(self, dist: str) -> str:
        return self.run(
            "-c", f"import importlib.metadata as m; print(m.version({dist!r}))"
        ).strip()

    def pytest(self, *paths: str) -> str:
        return self.run("-m", "pytest", "-q", "-p", "no:cacheprovider", *paths)


def newest_available(spec: SpecifierSet, env: Venv) -> Version | None:
    """The newest pymodbus release the index has within ``spec`` (None if pip cannot say)."""
    try:
        out = env.pip("index", "versions", "pymodbus")
    except AssertionError:
        return None
    m = re.search(r"Available versions: (.*)", out)
    if not m:
        return None
    versions = [Version(v.strip()) for v in m.group(1).split(",")]
    inside = [v for v in versions if v in spec and not v.is_prerelease]
    return max(inside) if inside else None


def test_pip_install_leaves_an_installed_pymodbus_alone(tmp_path: Path) -> None:
    env = Venv(tmp_path / "venv")
    env.pip("install", "--quiet", f"pymodbus=={OLDER_PYMODBUS}")
    report = tmp_path / "report.json"
    env.pip("install", "--quiet", "--report", str(report), str(ROOT))  # resolves deps
    installed = {i["metadata"]["name"].lower() for i in json.loads(report.read_text())["install"]}
    assert "drivebus" in installed and "pymodbus" not in installed, installed
    assert env.version("pymodbus") == OLDER_PYMODBUS
    env.pip("check")
    out = env.run("-c", (
        "import anyio, pymodbus\n"
        "from drivebus import Bus, LineSettings, SerialLine, __version__\n"
        "from drivebus.sim import RegisterSlave, VirtualWire\n"
        "S = LineSettings.parse('19200 8E1')\n"
        "async def main():\n"
        "    async with VirtualWire('beside') as wire:\n"
        "        wire.attach(RegisterSlave(5, S, initial=[(0, 4711)]))\n"
        "        async with Bus(SerialLine(wire.url, S), timeout=0.2) as bus:\n"
        "            print(await bus.slave(5).read_holding_registers(0, 1))\n"
        "anyio.run(main)\n"
        "print('drivebus', __version__, 'beside pymodbus', pymodbus.__version__)\n"
    ))
    assert "[4711]" in out and f"beside pymodbus {OLDER_PYMODBUS}" in out, out
    drivebus = subprocess.run(
        [str(Path(env.python).with_name("drivebus")), "--help"],
        capture_output=True, text=True, timeout=60,
    )
    assert drivebus.returncode == 0 and "scan" in drivebus.stdout, drivebus


@pytest.mark.parametrize(
    ("extra", "end"),
    [("test", "lowest"), ("bench", "lowest"), ("test+bench", "newest")],
)
def test_pymodbus_tests_pass_at_both_ends_of_the_range(
    tmp_path: Path, extra: str, end: str
) -> None:
    extras = extra.split("+")
    env = Venv(tmp_path / "venv")
    spec = extra_range(extras[0])
    for other in extras[1:]:
        spec &= extra_range(other)
    pins = [f"pymodbus=={lowest(spec)}"] if end == "lowest" else []
    runners = RUNNERS if "test" not in extras else []
    env.pip("install", "--quiet", f"{ROOT}[{','.join(extras)}]", *pins, *runners)
    got = Version(env.version("pymodbus"))
    assert got in spec, (got, spec)
    if end == "lowest":
        assert got == Version(lowest(spec))
    else:
        newest = newest_available(spec, env)
        if newest is not None:
            assert got == newest, (got, newest)
    out = env.pytest(*(PYMODBUS_TESTS if "test" in extras else BENCH_TESTS))
    assert re.search(r"\d+ passed", out) and "failed" not in out, out
    print(f"pymodbus {got} ({extra}, {end}): {out.strip().splitlines()[-1]}")


@pytest.fixture(scope="session")
def wheel(built_once: Callable[[str, Callable[[Path], None]], Path]) -> Path:
    (found,) = built_once("wheel", build_wheel).glob("drivebus-*.whl")
    return found


def test_the_extras_each_work_installed_from_another_folder(
    wheel: Path, tmp_path: Path
) -> None:
    """`pip install 'drivebus[bench,plots,parquet]'` (the wheel, not editable) into a
    fresh venv of the newest supported Python, then from a folder outside the checkout:
    the bench's quick efficiency run, its pymodbus baseline (bench) and its motion
    scenario on the packaged demo machine with a PNG of its moves (plots); a recording of
    a copy of the demo machine written as Parquet (parquet) and drawn as a PNG."""
    version = next((v for v in reversed(SUPPORTED) if find(v)), None)
    assert version is not None, f"none of the supported Pythons {SUPPORTED} found"
    python = find(version)
    assert python is not None
    work = tmp_path / "work"
    work.mkdir()
    env = Installed(install(python, wheel, tmp_path / "venv", "[bench,plots,parquet]"), work)
    env.ok("drivebus", "bench", "--quick", "--only", "efficiency", "--only",
           "pymodbus baseline", "--only", "motion", "--plots", "plots", "--json", "bench.json",
           timeout=900)
    rows = json.loads((work / "bench.json").read_text())
    assert {r["scenario"] for r in rows} == {"efficiency", "pymodbus baseline", "motion"}
    baseline = [r for r in rows if r["scenario"] == "pymodbus baseline"]
    assert baseline and all("note" not in r["figures"] for r in baseline), baseline
    assert (work / "plots" / "motion-group-moves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    env.ok("drivebus", "demo", "--write", "mine.toml")
    env.ok("drivebus", "record", "mine.toml", "x", "--during", "move x 50",
           "-o", "run.parquet", "--png", "run.png", timeout=300)
    assert (work / "run.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = env.ok("python", "-c", (
        "import pyarrow.parquet as pq\n"
        "t = pq.read_table('run.parquet')\n"
        "print(t.num_rows, ' '.join(t.column_names))\n"
    ))
    rows_read, columns = table.split(" ", 1)
    assert int(rows_read) > 0 and "position" in columns, table
