"""Every Python code block in README.md runs as written, on the simulator.

Each ```python block is written to a file and run by this interpreter in a fresh process
from the repository's root (as a reader who copies it would), with a timeout. A block that
raises, hangs or prints a traceback fails the test named after the block's section.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
TIMEOUT = 90.0


def python_blocks(text: str) -> list[tuple[str, str]]:
    """``(section heading, code)`` of each fenced ```python block, in order."""
    blocks: list[tuple[str, str]] = []
    heading = "(top)"
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("#") and not line.startswith("#!"):
            heading = line.lstrip("#").strip()
        fence = re.fullmatch(r"(`{3,})\s*python\s*", line)
        if fence:
            end = i + 1
            while end < len(lines) and lines[end].strip() != fence.group(1):
                end += 1
            if end == len(lines):
                raise AssertionError(f"README.md: the python block at line {i + 1} never ends")
            blocks.append((heading, "\n".join(lines[i + 1 : end]) + "\n"))
            i = end
        i += 1
    return blocks


BLOCKS = python_blocks(README.read_text(encoding="utf-8"))


def _ids() -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for heading, _ in BLOCKS:
        seen[heading] = seen.get(heading, 0) + 1
        out.append(heading if seen[heading] == 1 else f"{heading} #{seen[heading]}")
    return out


def test_the_readme_has_its_snippets() -> None:
    headings = {h for h, _ in BLOCKS}
    assert {"Using the bus", "Machines and axes", "The simulator"} <= headings, headings


def test_extraction_finds_fenced_blocks_only() -> None:
    text = "# A\n```sh\nmake\n```\n## B\n```python\nprint(1)\n```\n````python\nx = '```'\n````\n"
    assert python_blocks(text) == [("B", "print(1)\n"), ("B", "x = '```'\n")]


@pytest.mark.parametrize(("heading", "code"), BLOCKS, ids=_ids())
def test_readme_snippet_runs_as_written(heading: str, code: str, tmp_path: Path) -> None:
    script = tmp_path / "snippet.py"
    script.write_text(code, encoding="utf-8")
    try:
        done = subprocess.run(
            [sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True,
            timeout=TIMEOUT,
        )
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"README snippet in {heading!r} still running after {TIMEOUT} s:\n"
                    f"{exc.stdout!r}\n{exc.stderr!r}")
    report = f"README snippet in {heading!r}:\n--- stdout\n{done.stdout}\n--- stderr\n{done.stderr}"
    assert done.returncode == 0, report
    assert "Traceback" not in done.stderr, report
