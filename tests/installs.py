"""Installing drivebus as users do: the supported Pythons, a wheel built as a release is,
fresh venvs with it installed, and its commands run from a folder outside the checkout.

``SUPPORTED`` reads the ``Programming Language :: Python :: 3.N`` classifiers of
pyproject.toml (what the tests run on is what the package says it supports: one place).
``find(version)`` is an interpreter of that version on this machine or None: ``pythonX.Y``
on PATH, then pyenv's versions (``$PYENV_ROOT``, ``~/.pyenv``), then /usr/bin; each
candidate is run and asked its version (a pyenv shim on PATH exists for every version
pyenv knows, and fails for those not selected).

``python tests/installs.py 3.13`` prints that interpreter's path (the Makefile's
``test-py3.13`` uses it) or says where it looked and exits 1; ``--newest`` prints the
newest supported version (.ci/run tests it).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def supported() -> list[str]:
    """The ``3.N`` versions the classifiers of pyproject.toml name, oldest first."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    found = [m.group(1) for c in project["classifiers"]
             if (m := re.fullmatch(r"Programming Language :: Python :: (3\.\d+)", c))]
    return sorted(found, key=lambda v: tuple(map(int, v.split("."))))


SUPPORTED = supported()


def _candidates(version: str) -> list[str]:
    names = [shutil.which(f"python{version}")]
    pyenv = Path(os.environ.get("PYENV_ROOT") or Path.home() / ".pyenv") / "versions"
    names += [str(p) for p in sorted(pyenv.glob(f"{version}.*/bin/python{version}"),
                                     reverse=True)]  # the newest patch release first
    names.append(f"/usr/bin/python{version}")
    return [n for n in names if n and Path(n).is_file()]


def find(version: str) -> str | None:
    """A Python ``version`` (e.g. "3.13") interpreter on this machine, or None."""
    for exe in _candidates(version):
        try:
            done = subprocess.run(
                [exe, "-c", "import sys; print('%d.%d' % sys.version_info[:2])"],
                capture_output=True, text=True, timeout=30,
            )
        except (OSError, subprocess.TimeoutExpired):
            continue
        if done.returncode == 0 and done.stdout.strip() == version:
            return exe
    return None


SDIST = ("pyproject.toml", "README.md", "LICENSE", "src")
"""What a source distribution carries, and so all a release's wheel is built from."""


def build_wheel(out: Path) -> None:
    """A wheel built into ``out`` by pip from a copy of what an sdist carries, as a release
    is built: nothing else of the work tree (``build/``, ``configs/``, an egg-info, files
    beside the package) can reach it or make it work."""
    with tempfile.TemporaryDirectory() as tmp:
        source = Path(tmp) / "drivebus"
        source.mkdir()
        for name in SDIST:
            if (ROOT / name).is_dir():
                shutil.copytree(ROOT / name, source / name,
                                ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
            else:
                shutil.copy2(ROOT / name, source / name)
        subprocess.run(
            [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(out),
             str(source)],
            check=True, timeout=300, capture_output=True,
        )


class Installed:
    """A fresh venv of one Python with the wheel installed in it as users install it
    (not editable, its dependencies resolved by pip from the package index), whose
    commands run from ``work``, a folder outside the checkout."""

    def __init__(self, venv: Path, work: Path) -> None:
        self.bin = venv / "bin"
        self.work = work

    def run(self, *args: str, timeout: float = 180) -> subprocess.CompletedProcess[str]:
        """``args[0]`` of the venv (drivebus, python) with the rest, in ``work``."""
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
        return subprocess.run([str(self.bin / args[0]), *args[1:]], cwd=self.work, env=env,
                              capture_output=True, text=True, timeout=timeout)

    def ok(self, *args: str, timeout: float = 180) -> str:
        done = self.run(*args, timeout=timeout)
        assert done.returncode == 0, f"{' '.join(args)}:\n{done.stdout}\n{done.stderr}"
        return done.stdout


def install(python: str, wheel: Path, venv: Path, extras: str = "") -> Path:
    """A venv of ``python`` at ``venv`` with ``wheel`` (and ``extras``, e.g. "[bench]")
    installed by its own pip, dependencies from the package index; ``venv``."""
    subprocess.run([python, "-m", "venv", str(venv)], check=True, timeout=120,
                   capture_output=True)
    done = subprocess.run(
        [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet",
         "--disable-pip-version-check", f"{wheel}{extras}"],
        capture_output=True, text=True, timeout=900,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return venv


if __name__ == "__main__":
    if sys.argv[1:] == ["--newest"]:
        print(SUPPORTED[-1])
        sys.exit(0)
    wanted = sys.argv[1] if len(sys.argv) > 1 else SUPPORTED[-1]
    exe = find(wanted)
    if exe is None:
        sys.exit(f"no Python {wanted} here (looked for python{wanted} on PATH, under pyenv's "
                 f"versions and in /usr/bin)")
    print(exe)
