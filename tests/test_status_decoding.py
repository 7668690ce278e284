"""The status poll's decoding worked out once (``drives.command.decoding.Decoding``) gives what the
engine's own decoding gives, register by register, for every drive description: the
built-in families and the descriptions shipped in ``configs/drives``."""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Any

import pytest

from drivebus.drives.command.decoding import Decoding
from drivebus.drives.description import load_description
from drivebus.drives.engine import DescribedProfile
from drivebus.drives.registry import add_drives_path, all_families, family_from_description
from drivebus.drives.values import Table
from test_description_objects import MRJEC, write

add_drives_path(Path(__file__).resolve().parents[1] / "configs" / "drives")
DESCRIBED = sorted((f for f in all_families()
                    if isinstance(f.profile, type) and issubclass(f.profile, DescribedProfile)),
                   key=lambda f: f.name)


def plain(values: dict[str, Any]) -> dict[str, Any]:
    """Decoded values as comparable data (a table's entries, NaN as a word)."""
    out: dict[str, Any] = {}
    for k, v in values.items():
        if isinstance(v, Table):
            v = dict(v.items())
        elif isinstance(v, float) and math.isnan(v):
            v = "nan"
        out[k] = (type(v).__name__, v)
    return out


def test_an_object_addressed_status_decodes_as_the_engine_does(tmp_path: Path) -> None:
    """Its words sit by object, not by address (``OBJECT + (address << 8) + word``)."""
    fam = family_from_description(load_description(write(tmp_path, MRJEC)))
    test_the_status_poll_decodes_as_the_engine_does(fam)


@pytest.mark.parametrize("fam", DESCRIBED, ids=lambda f: f.name)
def test_the_status_poll_decodes_as_the_engine_does(fam: Any) -> None:
    cls = fam.profile
    plan = cls._status_plan
    rng = random.Random(37)
    for ppr in (200, 4000, 10000):
        profile = cls.__new__(cls)  # a decoder only: no drive, no I/O
        profile.last = {}
        profile.pulses_per_rev = ppr
        decoding = Decoding(plan, ppr)
        addresses = {a for step in decoding.steps for a in step[3]}
        for _ in range(20):
            words = {a: rng.choice((0, 1, 0x7FFF, 0x8000, 0xFFFF, rng.randrange(65536)))
                     for a in addresses}
            raw_a: dict[str, list[int]] = {}
            raw_b: dict[str, list[int]] = {}
            assert plain(decoding.decode(profile.description, profile.last, words, raw_a)) == \
                plain(profile._decode(plan, words, raw_b)), fam.name
            assert raw_a == raw_b
