"""Published endpoints: where a running drivebus process can be found by another one.

A ``drivebus sim`` publishes the pty of each simulated serial line under its ``sim://``
name; a ``drivebus serve`` publishes its URL under its machine file, so that one-shot
commands on that file talk to the process that owns the port instead of opening it. An
entry lives in a per-user runtime directory, names the process that wrote it, and counts
only while that process is alive.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

__all__ = ["lookup", "publish", "runtime_dir"]


def runtime_dir(kind: str) -> Path:
    """The directory of ``kind`` entries (``sim``, ``serve``) for this user."""
    base = os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    return Path(base) / f"drivebus-{os.getuid()}" / kind


def _file(kind: str, key: str) -> Path:
    if "/" in key or key in (".", "..") or not key:
        key = hashlib.sha256(key.encode()).hexdigest()[:32]
    return runtime_dir(kind) / key


def lookup(kind: str, key: str) -> list[str] | None:
    """The lines a live process published under ``key``, else None."""
    try:
        pid_text, *lines = _file(kind, key).read_text().split("\n")
        os.kill(int(pid_text), 0)
    except (OSError, ValueError):
        return None
    return [line for line in lines if line]


@contextlib.contextmanager
def publish(kind: str, entries: dict[str, Sequence[str]]) -> Iterator[list[str]]:
    """Publish ``entries`` (key -> lines) for the block; yields what could not be
    published (as messages: a warning, not an error); removed on exit."""
    written: list[Path] = []
    problems: list[str] = []
    try:
        runtime_dir(kind).mkdir(parents=True, exist_ok=True)
        for key, lines in entries.items():
            f = _file(kind, key)
            f.write_text("\n".join([str(os.getpid()), *lines]) + "\n")
            written.append(f)
    except OSError as exc:
        problems.append(f"cannot publish in {runtime_dir(kind)}: {exc}")
    try:
        yield problems
    finally:
        for f in written:
            f.unlink(missing_ok=True)
