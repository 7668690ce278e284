"""Expressions and templates of drive descriptions: a small, safe subset of Python.

A description computes register values, decodes status bits and states conditions with
one-line expressions such as ``"START_POSITION | (INTERRUPT if option.interrupt_moves else
0)"`` or ``"status.ALARM or error_code != 0"``. They are parsed with Python's own parser and
checked against a whitelist before they are compiled once: numbers, strings, names,
attributes (``option.x``, ``status.ENABLED``), subscripts (``path_pulses[path]``),
arithmetic and bit operators, comparisons, ``and``/``or``/``not``, ``a if c else b`` and
calls of the functions in ``FUNCTIONS``. Nothing else (no dunders, no lambdas, no
comprehensions), so a description is data: it cannot import or open anything.

Templates (``"CL86R (model code {model})"``, ``"{version >> 8}.{version & 0xFF:02d}"``)
hold expressions in braces, with an optional format spec after a colon.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from drivebus.errors import ConfigError

__all__ = ["FUNCTIONS", "Expr", "ExprError", "Template", "Unknown"]


class ExprError(ConfigError):
    """An expression or template that cannot be parsed, uses what is not allowed, or fails
    when it is evaluated (a description's mistake: a ``ConfigError``)."""


class Unknown(LookupError):
    """A name whose value is not known yet (a register not read yet, say): raised while
    an expression is evaluated ahead of the I/O that would give it."""


def _bit(value: int, n: int) -> bool:
    """Bit ``n`` of ``value``."""
    return bool((int(value) >> int(n)) & 1)


FUNCTIONS: dict[str, Callable[..., Any]] = {
    "abs": abs,
    "min": min,
    "max": max,
    "round": round,
    "int": int,
    "float": float,
    "bool": bool,
    "floor": math.floor,
    "ceil": math.ceil,
    "bit": _bit,
    "str": str,
    "len": len,
    "range": lambda *a: range(*(int(x) for x in a)),
    "upper": lambda s: str(s).upper(),
    "lower": lambda s: str(s).lower(),
}
"""The functions an expression may call."""

_BINOPS = (
    ast.Add, ast.Sub, ast.Mult, ast.Div, ast.FloorDiv, ast.Mod, ast.BitOr, ast.BitAnd,
    ast.BitXor, ast.LShift, ast.RShift,
)
_UNARY = (ast.USub, ast.UAdd, ast.Not, ast.Invert)
_COMPARE = (ast.Eq, ast.NotEq, ast.Lt, ast.LtE, ast.Gt, ast.GtE, ast.In, ast.NotIn, ast.Is,
            ast.IsNot)


def _check(node: ast.AST, names: set[str], paths: set[str]) -> None:
    """Refuse anything outside the whitelist; collect the names and dotted paths used."""
    if isinstance(node, ast.Expression):
        _check(node.body, names, paths)
    elif isinstance(node, ast.Constant):
        if not isinstance(node.value, int | float | str | bool | type(None)):
            raise ExprError(f"constant {node.value!r} is not allowed")
    elif isinstance(node, ast.Name):
        if node.id.startswith("_"):
            raise ExprError(f"name {node.id!r} is not allowed")
        names.add(node.id)
        paths.add(node.id)
    elif isinstance(node, ast.Attribute):
        if node.attr.startswith("_"):
            raise ExprError(f"attribute {node.attr!r} is not allowed")
        dotted = _dotted(node)
        if dotted is None:
            raise ExprError("attributes are allowed on names only (like option.speed)")
        names.add(dotted.split(".", 1)[0])
        paths.add(dotted)
    elif isinstance(node, ast.Subscript):
        _check(node.value, names, paths)
        _check(node.slice, names, paths)
    elif isinstance(node, ast.BinOp):
        if not isinstance(node.op, _BINOPS):
            raise ExprError(f"operator {type(node.op).__name__} is not allowed")
        _check(node.left, names, paths)
        _check(node.right, names, paths)
    elif isinstance(node, ast.UnaryOp):
        if not isinstance(node.op, _UNARY):
            raise ExprError(f"operator {type(node.op).__name__} is not allowed")
        _check(node.operand, names, paths)
    elif isinstance(node, ast.BoolOp):
        for v in node.values:
            _check(v, names, paths)
    elif isinstance(node, ast.Compare):
        if not all(isinstance(op, _COMPARE) for op in node.ops):
            raise ExprError("comparison operator not allowed")
        _check(node.left, names, paths)
        for c in node.comparators:
            _check(c, names, paths)
    elif isinstance(node, ast.IfExp):
        for part in (node.test, node.body, node.orelse):
            _check(part, names, paths)
    elif isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
            allowed = ", ".join(FUNCTIONS)
            raise ExprError(f"only these functions may be called: {allowed}")
        if node.keywords:
            raise ExprError("function calls take positional arguments only")
        for a in node.args:
            _check(a, names, paths)
    elif isinstance(node, ast.Tuple | ast.List):
        for e in node.elts:
            _check(e, names, paths)
    else:
        raise ExprError(f"{type(node).__name__} is not allowed in an expression")


def _dotted(node: ast.AST) -> str | None:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        head = _dotted(node.value)
        return None if head is None else f"{head}.{node.attr}"
    return None


class _Scope(Mapping[str, Any]):
    """The names an evaluation sees: the caller's mapping, then the functions."""

    __slots__ = ("_values",)

    def __init__(self, values: Mapping[str, Any]) -> None:
        self._values = values

    def __getitem__(self, key: str) -> Any:
        try:
            return self._values[key]
        except KeyError:
            if key in FUNCTIONS:
                return FUNCTIONS[key]
            raise

    def __iter__(self) -> Any:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)


_GLOBALS: dict[str, Any] = {"__builtins__": {}}
_WITH_FUNCTIONS: dict[str, Any] = {"__builtins__": {}, **FUNCTIONS}
"""The globals when the names come as a plain dict: the dict is looked in first, then
the functions (as ``_Scope`` does), with the dict's own fast lookups."""


@dataclass(frozen=True)
class Expr:
    """One checked, compiled expression; call it with a mapping of names to values."""

    source: str
    names: frozenset[str] = field(default=frozenset(), compare=False)
    """The top-level names it uses (``option`` for ``option.speed``)."""
    paths: frozenset[str] = field(default=frozenset(), compare=False)
    """The dotted names it uses (``option.speed``, ``status.ENABLED``)."""
    _code: Any = field(default=None, compare=False, repr=False)

    @classmethod
    def parse(cls, source: str | int | float | bool) -> Expr:
        """The expression ``source`` (a number or bool is a constant); ``ExprError`` if it
        is not one or uses what is not allowed."""
        if isinstance(source, bool | int | float):
            source = repr(source)
        if not isinstance(source, str) or not source.strip():
            raise ExprError(f"expected an expression, got {source!r}")
        try:
            tree = ast.parse(source.strip(), mode="eval")
        except SyntaxError as exc:
            raise ExprError(f"{source!r} is not an expression: {exc.msg}") from None
        names: set[str] = set()
        paths: set[str] = set()
        _check(tree, names, paths)
        code = compile(tree, "<description>", "eval")
        return cls(source.strip(), frozenset(names), frozenset(paths), code)

    @property
    def constant(self) -> bool:
        """True if it uses no names (its value is known without evaluating anything)."""
        return not (self.names - set(FUNCTIONS))

    @property
    def name(self) -> str | None:
        """The name if the expression is just one (dotted) name, else None."""
        src = self.source
        return src if src.replace(".", "").replace("_", "").isalnum() and src in self.paths \
            else None

    def __call__(self, values: Mapping[str, Any]) -> Any:
        """The expression's value with ``values`` for its names (``Unknown`` propagates;
        a name missing from ``values`` raises ``ExprError``)."""
        try:
            if type(values) is dict:
                return eval(self._code, _WITH_FUNCTIONS, values)  # checked by _check
            return eval(self._code, _GLOBALS, _Scope(values))  # checked by _check
        except NameError as exc:
            raise ExprError(f"{self.source!r}: {exc}") from None
        except Unknown:
            raise
        except (TypeError, ValueError, ZeroDivisionError, AttributeError, KeyError,
                IndexError, OverflowError) as exc:
            raise ExprError(f"{self.source!r}: {exc}") from None

    def __str__(self) -> str:
        return self.source


@dataclass(frozen=True)
class Template:
    """Text with ``{expression}`` or ``{expression:format}`` fields."""

    source: str
    parts: tuple[str | tuple[Expr, str], ...] = field(default=(), compare=False)

    @classmethod
    def parse(cls, source: str) -> Template:
        """The template ``source``; ``ExprError`` for a bad field or unbalanced braces."""
        parts: list[str | tuple[Expr, str]] = []
        text = ""
        i = 0
        while i < len(source):
            c = source[i]
            if c in "{}" and source[i + 1 : i + 2] == c:
                text += c
                i += 2
                continue
            if c == "}":
                raise ExprError(f"template {source!r}: '}}' without '{{'")
            if c != "{":
                text += c
                i += 1
                continue
            end = source.find("}", i)
            if end < 0:
                raise ExprError(f"template {source!r}: '{{' without '}}'")
            inner = source[i + 1 : end]
            body, spec = _split_spec(inner)
            if text:
                parts.append(text)
                text = ""
            parts.append((Expr.parse(body), spec))
            i = end + 1
        if text:
            parts.append(text)
        return cls(source, tuple(parts))

    @property
    def names(self) -> frozenset[str]:
        """The names its fields use."""
        out: set[str] = set()
        for p in self.parts:
            if not isinstance(p, str):
                out |= p[0].names
        return frozenset(out)

    @property
    def paths(self) -> frozenset[str]:
        """The dotted names its fields use."""
        out: set[str] = set()
        for p in self.parts:
            if not isinstance(p, str):
                out |= p[0].paths
        return frozenset(out)

    def __call__(self, values: Mapping[str, Any]) -> str:
        """The text with each field's value formatted in."""
        out = []
        for p in self.parts:
            if isinstance(p, str):
                out.append(p)
                continue
            expr, spec = p
            value = expr(values)
            try:
                out.append(format(value, spec))
            except (TypeError, ValueError) as exc:
                raise ExprError(f"template {self.source!r}: {exc}") from None
        return "".join(out)

    def __str__(self) -> str:
        return self.source


def _split_spec(inner: str) -> tuple[str, str]:
    """``expr:spec`` split at the first colon outside brackets and quotes."""
    depth = 0
    quote = ""
    for i, c in enumerate(inner):
        if quote:
            if c == quote:
                quote = ""
        elif c in "'\"":
            quote = c
        elif c in "([":
            depth += 1
        elif c in ")]":
            depth -= 1
        elif c == ":" and depth == 0:
            return inner[:i], inner[i + 1 :]
    return inner, ""
