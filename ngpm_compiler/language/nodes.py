"""Syntax nodes of a parsed .lsys grammar (parser.py builds them, checker.py checks them)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field


@dataclass
class Node:
    line: int
    col: int


# ---- expressions -------------------------------------------------------------------------


@dataclass
class Num(Node):
    value: float


@dataclass
class Var(Node):
    name: str


@dataclass
class Unary(Node):
    op: str  # "-", "+", "not"
    operand: Expr


@dataclass
class Binary(Node):
    op: str  # + - * / % ^ < <= > >= == != and or
    left: Expr
    right: Expr


@dataclass
class Call(Node):
    name: str
    args: list[Expr]
    text: str = ""  # the call's source text


Expr = Num | Var | Unary | Binary | Call


def walk(expr: Expr) -> Iterator[Expr]:
    """Yield every node of an expression, outer before inner, left to right."""
    yield expr
    if isinstance(expr, Unary):
        yield from walk(expr.operand)
    elif isinstance(expr, Binary):
        yield from walk(expr.left)
        yield from walk(expr.right)
    elif isinstance(expr, Call):
        for arg in expr.args:
            yield from walk(arg)


# ---- statements --------------------------------------------------------------------------


@dataclass
class ModuleUse(Node):
    """A module in a successor or axiom: `F(LEN)`, `+`, `~l(2, 1)`."""

    name: str
    args: list[Expr]
    explicit_args: bool = False  # written with parentheses


@dataclass
class Successor(Node):
    modules: list[ModuleUse]
    text: str = ""


@dataclass
class Rule(Node):
    """One alternative `Pred(params) : cond --> successor : prob`."""

    pred: str
    params: list[str]
    param_pos: list[tuple[int, int]]
    cond: Expr | None
    cond_text: str
    successor: Successor
    prob: Expr | None
    section: str  # "production" or "interpretation"
    text: str = ""  # the whole rule's source text (all alternatives of its line)
    end_line: int = 0


@dataclass
class Define(Node):
    name: str
    expr: Expr
    text: str = ""


@dataclass
class ModuleDecl(Node):
    name: str
    params: list[str]


@dataclass
class Header(Node):
    """`derivation length:`, `viewport:`, `angle:`, `start:`, `max primitives:`,
    `max modules:`."""

    kind: str
    values: list[Expr]


@dataclass
class Grammar:
    filename: str
    source: str
    defines: list[Define] = field(default_factory=list)
    decls: list[ModuleDecl] = field(default_factory=list)
    axiom: Successor | None = None
    headers: dict[str, Header] = field(default_factory=dict)
    rules: list[Rule] = field(default_factory=list)
