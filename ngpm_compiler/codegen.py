"""Emit the Python sampler module of a checked grammar (docs/architecture.md section 2)."""

from __future__ import annotations

import json
import math
import textwrap
from collections.abc import Callable
from typing import TYPE_CHECKING

from ngpm_compiler.nodes import Binary, Call, Expr, Num, Unary, Var

if TYPE_CHECKING:
    from ngpm_compiler.checker import Alt, Checked, Group, Resolved, RuleSet

# Python precedence of each operator (higher binds tighter).
PREC = {"or": 1, "and": 2, "not": 3, "<": 4, "<=": 4, ">": 4, ">=": 4, "==": 4, "!=": 4,
        "+": 5, "-": 5, "*": 6, "/": 6, "%": 6, "neg": 7, "atom": 9}
BOOL_OPS = {"or", "and", "not", "<", "<=", ">", ">=", "==", "!="}
RANDOM_METHOD = {"normal": "normal", "uniform": "uniform", "bernoulli": "bernoulli",
                 "categorical": "categorical"}

# Math functions: templates over the printed arguments. Angles are degrees.
FUNC_TEMPLATES: dict[str, Callable[[list[str]], str]] = {
    "sin": lambda a: f"math.sin(math.radians({a[0]}))",
    "cos": lambda a: f"math.cos(math.radians({a[0]}))",
    "tan": lambda a: f"math.tan(math.radians({a[0]}))",
    "asin": lambda a: f"math.degrees(math.asin({a[0]}))",
    "acos": lambda a: f"math.degrees(math.acos({a[0]}))",
    "atan": lambda a: f"math.degrees(math.atan({a[0]}))",
    "atan2": lambda a: f"math.degrees(math.atan2({a[0]}, {a[1]}))",
    "sqrt": lambda a: f"math.sqrt({a[0]})",
    "exp": lambda a: f"math.exp({a[0]})",
    "log": lambda a: f"math.log({a[0]})",
    "pow": lambda a: f"math.pow({a[0]}, {a[1]})",
    "abs": lambda a: f"abs({a[0]})",
    "min": lambda a: f"min({', '.join(a)})",
    "max": lambda a: f"max({', '.join(a)})",
    "floor": lambda a: f"float(math.floor({a[0]}))",
    "ceil": lambda a: f"float(math.ceil({a[0]}))",
    "round": lambda a: f"float(math.floor({a[0]} + 0.5))",
}
# (min args, max args or None) of every function, random ones included.
FUNCTION_ARITY: dict[str, tuple[int, int | None]] = {
    "sin": (1, 1), "cos": (1, 1), "tan": (1, 1), "asin": (1, 1), "acos": (1, 1),
    "atan": (1, 1), "atan2": (2, 2), "sqrt": (1, 1), "exp": (1, 1), "log": (1, 1),
    "pow": (2, 2), "abs": (1, 1), "min": (2, None), "max": (2, None), "floor": (1, 1),
    "ceil": (1, 1), "round": (1, 1),
}
# Random calls: name -> (site kind, min args, max args or None)
RANDOM_CALLS: dict[str, tuple[str, int, int | None]] = {
    "gauss": ("normal", 2, 2), "normal": ("normal", 2, 2), "uniform": ("uniform", 2, 2),
    "flip": ("bernoulli", 1, 1), "bernoulli": ("bernoulli", 1, 1),
    "categorical": ("categorical", 2, None), "choice": ("categorical", 2, None),
}
BUILTIN_NAMES = {"pi": "math.pi"}


def py_float(value: float) -> str:
    """A float literal: `2.0`, `0.75`, `1e-05`."""
    text = repr(float(value))
    return text if math.isfinite(value) else f"float({text!r})"


def is_bool(expr: Expr) -> bool:
    return (isinstance(expr, Binary) and expr.op in BOOL_OPS) or (
        isinstance(expr, Unary) and expr.op == "not")


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
            return py_float(expr.value), PREC["atom"] if expr.value >= 0 else PREC["neg"]
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
            site = self.sites[id(expr)]
            if kind == "categorical":
                return f"ctx.categorical({site}, ({', '.join(args)}))"
            return f"ctx.{RANDOM_METHOD[kind]}({site}, {', '.join(args)})"
        return FUNC_TEMPLATES[expr.name](args)


# ---- the module ----------------------------------------------------------------------------

LIMIT = 100  # line length of the generated code (ruff's setting)


def q(text: str) -> str:
    """A double-quoted Python string literal."""
    return json.dumps(text)


def pack(head: str, items: list[str], cont: str, tail: str) -> list[str]:
    """`head` + comma-separated items, wrapped at LIMIT with `cont` as continuation indent."""
    lines, cur = [], head
    for i, item in enumerate(items):
        piece = item + (tail if i == len(items) - 1 else ",")
        if cur not in (head,) and len(cur) + 1 + len(piece) > LIMIT:
            lines.append(cur)
            cur = cont + piece
        else:
            cur = cur + ("" if cur == head else " ") + piece
    lines.append(cur)
    return lines


def noqa(line: str) -> str:
    return line + "  # noqa: E501" if len(line) > LIMIT else line


class ModuleWriter:
    def __init__(self, checked: Checked, source_path: str, grammar_hash: str) -> None:
        self.c = checked
        self.source_path = source_path
        self.base = source_path.replace("\\", "/").rsplit("/", 1)[-1]
        self.grammar_hash = grammar_hash

    def docstring(self, texts: list[str], first: int, last: int, indent: str) -> list[str]:
        where = f"({self.base}:{first})" if first == last else f"({self.base}:{first}-{last})"
        rows = []
        for text in texts:
            parts = [p.strip() for p in text.replace("\\", "\\\\").replace('"', '\\"')
                     .splitlines() if p.strip()]
            rows += parts[:1] + ["    " + p for p in parts[1:]]
        one = f'{indent}"""{rows[0]}   {where}"""' if len(rows) == 1 else ""
        if one and len(one) <= LIMIT:
            return [one]
        out: list[str] = []
        for row in rows + [where]:
            lead = row[: len(row) - len(row.lstrip())]
            out += textwrap.wrap(row, LIMIT - len(indent) - 3, subsequent_indent=lead + "    ",
                                 break_long_words=True, break_on_hyphens=False) or [""]
        out = [indent + line for line in out]
        out[0] = indent + '"""' + out[0][len(indent):]
        return out + [indent + '"""']

    def successor(self, mods: list[Resolved], printer: ExprPrinter, indent: str) -> list[str]:
        items = []
        for m in mods:
            args = [printer.number(a) for a in m.args]
            items.append("(" + ", ".join([q(m.name)] + args) + ("," if not args else "") + ")")
        one = f"{indent}return [{', '.join(items)}]"
        if len(one) <= LIMIT:
            return [one]
        return ([f"{indent}return ["] + [noqa(f"{indent}    {it},") for it in items]
                + [f"{indent}]"])

    def group(self, group: Group, names: dict[str, str], rs_params: list[str],
              indent: str) -> list[str]:
        def printer_for(alt: Alt) -> ExprPrinter:
            local = dict(names)
            local.update(zip(alt.rule.params, rs_params, strict=False))
            return ExprPrinter(local, self.c.call_sites)

        alts = group.alts
        if len(alts) == 1:
            return self.successor(alts[0].modules, printer_for(alts[0]), indent)
        probs = ", ".join(py_float(a.prob or 0.0) for a in alts)
        lines = [noqa(f"{indent}alt = ctx.choose({group.site}, ({probs}))")]
        for i, alt in enumerate(alts):
            if i < len(alts) - 1:
                lines.append(f"{indent}if alt == {i}:")
                lines += self.successor(alt.modules, printer_for(alt), indent + "    ")
            else:
                lines += self.successor(alt.modules, printer_for(alt), indent)
        return lines

    def function(self, fname: str, rs: RuleSet) -> list[str]:
        rules = [a.rule for g in rs.groups for a in g.alts]
        texts = list(dict.fromkeys(r.text for r in rules))
        first = min(r.line for r in rules)
        last = max(r.end_line or r.line for r in rules)
        lines = [f"def {fname}({', '.join(['ctx'] + rs.params)}):"]
        lines += self.docstring(texts, first, last, "    ")
        for group in rs.groups:
            names = dict(self.c.const_names)
            names.update(zip(group.rule.params, rs.params, strict=False))
            if group.cond is None:
                lines += self.group(group, names, rs.params, "    ")
            else:
                cond = ExprPrinter(names, self.c.call_sites)(group.cond)
                lines.append(noqa(f"    if {cond}:"))
                lines += self.group(group, names, rs.params, "        ")
        if rs.groups[-1].cond is not None:
            lines.append("    return None  # no rule applies: the module stays as it is")
        return lines

    def site(self, s) -> list[str]:
        items = [f"index={s.index}", f"id={q(s.id)}", f"kind={q(s.kind)}", f"name={q(s.name)}",
                 f"module={q(s.module)}", f"arity={s.arity}"]
        if s.kind == "categorical":
            items.append(f"k={s.k}")
        if s.probs is not None:
            items.append("probs=(" + ", ".join(py_float(p) for p in s.probs) + ")")
        items += [f"line={s.line}", f"col={s.col}", f"source={q(s.source)}"]
        return [noqa(x) for x in pack("    Site(", items, "         ", "),")]

    def constants(self) -> list[str]:
        if not self.c.constants:
            return []
        lines_ = [d.line for d in self.c.grammar.defines]
        first, last = min(lines_), max(lines_)
        where = f"{first}" if first == last else f"{first}-{last}"
        out = [f"# constants ({self.base}:{where})"]
        for (py, value, _, _), d in zip(self.c.constants, self.c.grammar.defines, strict=True):
            line = f"{py} = {py_float(value)}"
            if not isinstance(d.expr, Num):
                line += f"  # {d.text}"
            out.append(noqa(line))
        return out

    def program(self, prods: dict[str, str], interps: dict[str, str]) -> list[str]:
        c = self.c

        def mapping(key: str, d: dict[str, str]) -> list[str]:
            if not d:
                return [f"    {key}={{}},"]
            return ([f"    {key}={{"] + [f"        {q(k)}: {v}," for k, v in d.items()]
                    + ["    },"])

        vp = "None" if c.viewport is None else "(" + ", ".join(map(py_float, c.viewport)) + ")"
        lines = ["PROGRAM = Program(", f"    name={q(c.name)},",
                 f"    source={q(self.source_path)},",
                 f"    grammar_hash={q(self.grammar_hash)},", "    sites=SITES,",
                 "    axiom=axiom,"]
        lines += mapping("productions", prods) + mapping("interpretation", interps)
        lines += mapping("arity", {k: str(v) for k, v in c.arity.items()})
        lines += [
            f"    derivation_length={c.derivation_length},",
            f"    angle={py_float(c.angle)},",
            f"    viewport={vp},",
            "    start=(" + ", ".join(map(py_float, c.start)) + "),",
            f"    max_primitives={c.max_primitives},",
        ]
        if c.max_modules is not None:  # only when the grammar sets it: older output unchanged
            lines.append(f"    max_modules={c.max_modules},")
        lines += [
            ")",
        ]
        return [noqa(x) for x in lines]

    def write(self) -> str:
        c = self.c
        body: list[str] = []
        axiom_text = c.grammar.axiom.text if c.grammar.axiom else ""
        body += ["", "", "def axiom(ctx):"]
        body += self.docstring([f"Axiom: {axiom_text}"], c.grammar.axiom.line,
                               c.grammar.axiom.line, "    ")
        body += self.successor(c.axiom, ExprPrinter(c.const_names, c.call_sites), "    ")
        prods: dict[str, str] = {}
        interps: dict[str, str] = {}
        for section, prefix, table in ((c.productions, "produce_", prods),
                                       (c.interpretation, "interpret_", interps)):
            for pred, rs in section.items():
                table[pred] = prefix + pred
                body += ["", ""] + self.function(prefix + pred, rs)
        sites = ["SITES = ["] + [x for s in c.sites for x in self.site(s)] + ["]"]
        if not c.sites:
            sites = ["SITES = []"]
        tail = ["", ""] + self.program(prods, interps)
        code = "\n".join(body + tail)
        head = [f'"""Generated by ngpmc from {self.source_path} -- do not edit."""'.replace(
            "\\", "/"), ""]
        if "math." in code:
            head += ["import math", ""]
        head.append("from ngpm_runtime.program import Program" + (", Site" if c.sites else ""))
        const = self.constants()
        head += [""] + (const + [""] if const else []) + sites
        return "\n".join(head) + "\n" + code + "\n"


def generate(checked: Checked, source_path: str, grammar_hash: str) -> str:
    """The Python source of the sampler module."""
    return ModuleWriter(checked, source_path, grammar_hash).write()
