"""Printing checked expressions as Python source (the checker and code generator share it)."""

from __future__ import annotations

import math

from ngpm_runtime.inference.sitekinds import KINDS

from ngpm_compiler.language.nodes import Binary, Call, Expr, Num, Unary, Var
from ngpm_compiler.language.tables import (
    BOOL_OPS,
    BUILTIN_NAMES,
    FUNC_TEMPLATES,
    PREC,
    RANDOM_CALLS,
)

Literal = str | float | int | None | tuple["Literal", ...]


def escape(text: str) -> str:
    """`text` for inside a double-quoted Python string or a comment: printable ASCII but
    `\\` and `"` stays, every other character becomes an escape (`\\n`, `\\x00`, `\\u2028`),
    so the result can end no string, comment or line."""
    if text.isascii() and text.isprintable() and "\\" not in text and '"' not in text:
        return text
    return "".join(_escape_char(c) for c in text)


def _escape_char(c: str) -> str:
    if c in '\\"':
        return "\\" + c
    return c if " " <= c <= "~" else ascii(c)[1:-1]


def q(value: Literal) -> str:
    """The Python literal of a value: the one way generated code gets a string, a number,
    None or a tuple of them. Text is escaped (`escape`); floats print as `2.0`, `1e-05`,
    `float("inf")`."""
    if value is None:
        return "None"
    if isinstance(value, str):
        return '"' + escape(value) + '"'
    if isinstance(value, tuple):
        items = [q(v) for v in value]
        return "(" + ", ".join(items) + ("," if len(items) == 1 else "") + ")"
    if isinstance(value, int) and not isinstance(value, bool):
        return str(int(value))
    if isinstance(value, float):
        text = repr(float(value))
        return text if math.isfinite(value) else f"float({q(text)})"
    raise TypeError(f"no Python literal for {type(value).__name__}")


def is_bool(expr: Expr) -> bool:
    return (isinstance(expr, Binary) and expr.op in BOOL_OPS) or (
        isinstance(expr, Unary) and expr.op == "not"
    )


class ExprPrinter:
    """Prints an expression as Python source.

    `names` maps a grammar identifier to its Python name; `sites` maps id(Call) of a random
    call to its site index."""

    def __init__(self, names: dict[str, str], sites: dict[int, int] | None = None) -> None:
        self.names = names
        self.sites = sites or {}

    def __call__(self, expr: Expr) -> str:
        return self.expr(expr)[0]

    def number(self, expr: Expr) -> str:
        """Print a value that must be a float (bools become 0.0 / 1.0)."""
        text, _ = self.expr(expr)
        return self.as_float(expr, text) if is_bool(expr) else text

    @staticmethod
    def as_float(expr: Expr, text: str) -> str:
        """A logical value as 1.0 / 0.0 (`and` / `or` return an operand in Python)."""
        if isinstance(expr, Binary) and expr.op in ("and", "or"):
            return f"float(bool({text}))"
        return f"float({text})"

    def wrap(self, expr: Expr, min_prec: int) -> str:
        text, prec = self.expr(expr)
        if is_bool(expr) and min_prec >= PREC["+"]:
            return self.as_float(expr, text)
        return f"({text})" if prec < min_prec else text

    def expr(self, expr: Expr) -> tuple[str, int]:
        if isinstance(expr, Num):
            return q(expr.value), PREC["atom"] if expr.value >= 0 else PREC["neg"]
        if isinstance(expr, Var):
            return self.names.get(expr.name) or BUILTIN_NAMES[expr.name], PREC["atom"]
        if isinstance(expr, Unary):
            if expr.op == "not":
                return f"not {self.wrap(expr.operand, PREC['not'])}", PREC["not"]
            return f"{expr.op}{self.wrap(expr.operand, PREC['neg'])}", PREC["neg"]
        if isinstance(expr, Binary):
            return self.binary(expr)
        return self.call(expr), PREC["atom"]

    def binary(self, expr: Binary) -> tuple[str, int]:
        op = expr.op
        if op == "^":
            return f"math.pow({self.number(expr.left)}, {self.number(expr.right)})", PREC["atom"]
        prec = PREC[op]
        if prec == PREC["<"]:  # comparisons never chain
            left, right = self.wrap(expr.left, prec + 1), self.wrap(expr.right, prec + 1)
        else:
            left, right = self.wrap(expr.left, prec), self.wrap(expr.right, prec + 1)
        return f"{left} {op} {right}", prec

    def call(self, expr: Call) -> str:
        args = [self.number(a) for a in expr.args]
        if expr.name in RANDOM_CALLS:
            kind = RANDOM_CALLS[expr.name][0]
            site = q(self.sites[id(expr)])
            if KINDS[kind].weighted:  # the weights go as one tuple
                return f"ctx.categorical({site}, ({', '.join(args)}))"
            return f"ctx.{kind}({site}, {', '.join(args)})"
        return FUNC_TEMPLATES[expr.name](args)
