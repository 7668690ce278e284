"""The documentation site builds with `mkdocs build --strict`, and says what the code says.

The build is the real one (`make docs`): mkdocs-material, mkdocstrings and the hook that
fills each drive family's page from its profile. The built pages are then checked
against the profiles' declarations, and the guide's complete programs are run.
"""

from __future__ import annotations

import html
import importlib
import importlib.util
import os
import re
import subprocess
import sys
import tomllib
from collections.abc import Callable
from pathlib import Path

import pytest

from drivebus.drives.registry import FAMILIES

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_readme import python_blocks  # noqa: E402

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("mkdocs") is None
    or importlib.util.find_spec("mkdocstrings_handlers") is None,
    reason="the docs extra is not installed (pip install -e '.[docs]'; make test does)",
)


def build_site(out: Path) -> None:
    """``mkdocs build --strict`` into ``out``, without a warning."""
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "WARNING" not in done.stderr, done.stderr


@pytest.fixture(scope="session")
def site(built_once: Callable[[str, Callable[[Path], None]], Path]) -> Path:
    return built_once("site", build_site)


def text_of(page: Path) -> str:
    """The visible text of a built page, whitespace collapsed."""
    raw = page.read_text(encoding="utf-8")
    raw = re.sub(r"<(script|style)\b.*?</\1>", " ", raw, flags=re.S)
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", raw)).split())


def test_every_page_is_built(site: Path) -> None:
    for page in ("index.html", "guide/wiring/index.html", "guide/line-settings/index.html",
                 "guide/per-slave-settings/index.html", "guide/simulator/index.html",
                 "guide/machines/index.html", "guide/service/index.html",
                 "guide/embedding/index.html",
                 "changelog/index.html", "drives/index.html"):
        assert (site / page).is_file(), page
    assert "Keep a Changelog" in text_of(site / "changelog/index.html")
    assert "[lines.rs485]" in text_of(site / "guide/machines/index.html")  # the template
    service = text_of(site / "guide/service/index.html")
    assert "SupplementaryGroups=dialout" in service and "Being written" not in service
    assert "drivebus_axis_position_meters" in service
    assert "problems.install(app)" in text_of(site / "guide/embedding/index.html")


@pytest.mark.parametrize("name", list(FAMILIES))
def test_family_page_states_the_declarations(site: Path, name: str) -> None:
    p = FAMILIES[name].profile
    text = text_of(site / "drives" / name.lower() / "index.html")
    assert f"Generated from {p.__module__}.{p.__qualname__}" in text
    for baud in p.baud_rates:
        assert str(baud) in text
    for fmt in p.line_formats:
        assert fmt in text
    for method in p.homing_methods:
        assert method in text
    for option, field in p.options.model_fields.items():
        assert option in text, option
        del field
    for code, meaning in p.exception_texts.items():
        assert " ".join(meaning.split()) in text, code
    assert "Registers" in text and "At a glance" in text


def test_install_page_states_the_pymodbus_ranges(site: Path) -> None:
    text = text_of(site / "guide/install/index.html")
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"
    ]
    for extra in ("bench", "test"):
        (pin,) = [r for r in extras[extra] if r.startswith("pymodbus")]
        assert pin in text, (extra, pin)


def test_families_table_lists_every_family(site: Path) -> None:
    text = text_of(site / "drives/index.html")
    for f in FAMILIES.values():
        assert f.description in text


@pytest.mark.parametrize(
    ("page", "names"),
    [
        ("drivebus", ["drivebus.Bus", "drivebus.SerialLine", "drivebus.open_machine",
                      "drivebus.Axis", "drivebus.LineSettings", "drivebus.Bus.slave",
                      # the axis's commands from its rooms (actor, jog, io) are documented
                      "drivebus.Axis.stop", "drivebus.Axis.jog", "drivebus.Axis.watch",
                      "drivebus.Axis.set_output", "drivebus.Axis.move_to"]),
        ("app", ["drivebus.app.MachineSession", "drivebus.app.EventHub"]),
        ("errors", ["drivebus.errors.DrivebusError", "drivebus.errors.NotSupported",
                    "drivebus.errors.ResponseTimeout"]),
        ("drives", ["drivebus.drives.DriveProfile", "drivebus.drives.nt_family.NT86Profile",
                    "drivebus.drives.od_drive.ODDriveProfile", "drivebus.drives.Register"]),
        ("sim", ["drivebus.sim.VirtualWire", "drivebus.sim.RegisterSlave",
                 "drivebus.sim.Fault"]),
    ],
)
def test_api_reference_from_docstrings(site: Path, page: str, names: list[str]) -> None:
    built = site / "api" / page / "index.html"
    raw, text = built.read_text(encoding="utf-8"), text_of(built)
    for dotted in names:
        assert f'id="{dotted}"' in raw, dotted  # mkdocstrings rendered the object
        module, _, attr = dotted.rpartition(".")
        try:
            obj = getattr(importlib.import_module(module), attr)
        except ImportError:  # a method: Class.method
            module, _, cls = module.rpartition(".")
            obj = getattr(getattr(importlib.import_module(module), cls), attr)
        summary = " ".join((obj.__doc__ or "").strip().split("\n\n")[0].split())
        summary = re.sub(r"``([^`]+)``", r"\1", summary)
        squeeze = re.compile(r"\s+")  # tags around code spans leave spaces in the text
        assert summary and squeeze.sub("", summary) in squeeze.sub("", text), (dotted, summary)


PROGRAMS = [
    (f"{md.relative_to(ROOT)}: {heading}", code)
    for md in sorted((ROOT / "docs").rglob("*.md"))
    for heading, code in python_blocks(md.read_text(encoding="utf-8"))
    if "anyio.run(" in code  # a complete program, not a fragment
]


def test_the_guide_has_programs() -> None:
    assert len(PROGRAMS) >= 2


@pytest.mark.parametrize(("where", "code"), PROGRAMS, ids=[w for w, _ in PROGRAMS])
def test_guide_programs_run_as_written(where: str, code: str, tmp_path: Path) -> None:
    script = tmp_path / "program.py"
    script.write_text(code, encoding="utf-8")
    done = subprocess.run(
        [sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True, timeout=90
    )
    assert done.returncode == 0, f"{where}:\n{done.stdout}\n{done.stderr}"


def test_drive_pages_are_committed_as_the_profiles_declare_them() -> None:
    """docs/drives/*.md hold the generated pages (no placeholder), current with the code,
    consistent with the procedures, and cite no path of drivebus's build environment."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("drive_pages",
                                                  ROOT / "docs/hooks/drive_pages.py")
    assert spec is not None and spec.loader is not None
    pages = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(pages)
    index = (ROOT / "docs/drives/index.md").read_text()
    assert index == pages.index_text(index), "run python docs/hooks/drive_pages.py"
    for name, fam in FAMILIES.items():
        text = (ROOT / "docs/drives" / f"{name.lower()}.md").read_text()
        assert text == pages.page_text(fam), f"{name}: run python docs/hooks/drive_pages.py"
        assert "## Parameters" in text and "shared/" not in text and "/work/" not in text
        for p in fam.profile.parameters():
            assert f"| `{p.key}` |" in text
    bhss = (ROOT / "docs/drives/bhss.md").read_text()
    assert "| save parameters | yes |" not in bhss  # it raises NotSupported by default
    assert "| save parameters | no: the BHSS drive has no save command" in bhss


def test_the_reference_names_every_key_of_an_example() -> None:
    """Each key an ``[[examples]]`` entry takes has its row in the reference's table (a
    user writing a frame the description cannot run found ``listed`` only in another
    description)."""
    from drivebus.drives.description.examples import ExampleDef

    text = (ROOT / "docs/reference/descriptions.md").read_text(encoding="utf-8")
    section = text.split("## `[[examples]]`", 1)[1].split("\n## ", 1)[0]
    for name, field in ExampleDef.model_fields.items():
        key = field.alias or name
        assert f"`{key}`" in section or f"`{key} =" in section, key
