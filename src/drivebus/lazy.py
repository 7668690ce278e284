"""Public names imported on first use (PEP 562) by a package's ``__init__``.

A package lists where each of its public names lives; importing the package (or any module
inside it) then loads none of them, so a command that needs one module of a package does
not pay for the package's other rooms (``drivebus --help`` loads no motion layer, a
register read no drive description).
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(
    package: str, homes: Mapping[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` for ``package``: name -> the module it lives in
    (imported at the first use of the name, which is then kept in the package)."""

    def get(name: str) -> Any:
        home = homes.get(name)
        if home is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(home), name)
        setattr(sys.modules[package], name, value)
        return value

    def names() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(homes))

    return get, names
