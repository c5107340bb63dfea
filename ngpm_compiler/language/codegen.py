"""Emit the Python sampler module of a checked grammar (docs/architecture.md section 2)."""

from __future__ import annotations

import textwrap

from ngpm_runtime.inference.sitekinds import KINDS
from ngpm_runtime.program import HEADER_END, HEADER_START, PROTOCOL, Site

from ngpm_compiler.language.checker import Alt, Checked, Group, Resolved, RuleSet
from ngpm_compiler.language.errors import ErrorSink
from ngpm_compiler.language.expr import ExprPrinter, escape, q
from ngpm_compiler.language.nodes import Expr, Num, Successor

# ---- the module ----------------------------------------------------------------------------

LIMIT = 100  # line length of the generated code (ruff's setting)
# Most nested brackets in one printed expression: Python refuses more than 200 in a line, and
# a successor puts an expression inside two (`return [("F", ...)]`).
MAX_BRACKETS = 198


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
        self.sink = ErrorSink(checked.grammar.filename, checked.grammar.source)

    def fits(self, text: str, expr: Expr) -> str:
        """`text`, the printed `expr`, unless it nests more brackets than Python reads: then
        a GrammarError at the expression."""
        depth = most = 0
        for c in text:
            if c in "([":
                depth += 1
                most = max(most, depth)
            elif c in ")]":
                depth -= 1
        if most > MAX_BRACKETS:
            raise self.sink.error(
                f"expression nested too deeply for Python ({most} levels of "
                f"parentheses in the generated code, at most {MAX_BRACKETS})",
                expr.line,
                expr.col,
            )
        return text

    def docstring(self, texts: list[str], first: int, last: int, indent: str) -> list[str]:
        """The .lsys lines, then `(file:first-last)`, for the reader (the runtime's messages
        read LOCATIONS). Rows are wrapped, then escaped: no text can end the docstring."""
        where = f"({self.base}:{first})" if first == last else f"({self.base}:{first}-{last})"
        rows = []
        for text in texts:
            parts = [p.strip() for p in text.splitlines() if p.strip()]
            rows += parts[:1] + ["    " + p for p in parts[1:]]
        one = f'{indent}"""{escape(rows[0])}   {escape(where)}"""' if len(rows) == 1 else ""
        if one and len(one) <= LIMIT:
            return [one]
        out: list[str] = []
        for row in rows:
            lead = row[: len(row) - len(row.lstrip())]
            out += textwrap.wrap(
                row,
                LIMIT - len(indent) - 3,
                subsequent_indent=lead + "    ",
                break_long_words=True,
                break_on_hyphens=False,
            ) or [""]
        out = [indent + escape(line) for line in out + [where]]
        out[0] = indent + '"""' + out[0][len(indent) :]
        return out + [indent + '"""']

    def successor(self, mods: list[Resolved], printer: ExprPrinter, indent: str) -> list[str]:
        items = []
        for m in mods:
            args = [self.fits(printer.number(a), a) for a in m.args]
            items.append("(" + ", ".join([q(m.name)] + args) + ("," if not args else "") + ")")
        one = f"{indent}return [{', '.join(items)}]"
        if len(one) <= LIMIT:
            return [one]
        return [f"{indent}return ["] + [noqa(f"{indent}    {it},") for it in items] + [f"{indent}]"]

    def group(
        self, group: Group, names: dict[str, str], rs_params: list[str], indent: str
    ) -> list[str]:
        def printer_for(alt: Alt) -> ExprPrinter:
            local = dict(names)
            local.update(zip(alt.rule.params, rs_params, strict=False))
            return ExprPrinter(local, self.c.call_sites)

        alts = group.alts
        if len(alts) == 1:
            return self.successor(alts[0].modules, printer_for(alts[0]), indent)
        probs = ", ".join(q(float(a.prob or 0.0)) for a in alts)
        lines = [noqa(f"{indent}alt = ctx.choose({q(group.site)}, ({probs}))")]
        for i, alt in enumerate(alts):
            if i < len(alts) - 1:
                lines.append(f"{indent}if alt == {q(i)}:")
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
                cond = self.fits(ExprPrinter(names, self.c.call_sites)(group.cond), group.cond)
                lines.append(noqa(f"    if {cond}:"))
                lines += self.group(group, names, rs.params, "        ")
        if rs.groups[-1].cond is not None:
            lines.append("    return None  # no rule applies: the module stays as it is")
        return lines

    def site(self, s: Site) -> list[str]:
        items = [
            f"index={q(s.index)}",
            f"id={q(s.id)}",
            f"kind={q(s.kind)}",
            f"name={q(s.name)}",
            f"module={q(s.module)}",
            f"arity={q(s.arity)}",
        ]
        if KINDS[s.kind].weighted:  # k: the number of weights
            items.append(f"k={q(s.k)}")
        if s.probs is not None:
            items.append("probs=" + q(tuple(float(p) for p in s.probs)))
        items += [f"line={q(s.line)}", f"col={q(s.col)}", f"source={q(s.source)}"]
        return [noqa(x) for x in pack("    Site(", items, "         ", "),")]

    def constants(self) -> list[str]:
        if not self.c.constants:
            return []
        lines_ = [d.line for d in self.c.grammar.defines]
        first, last = min(lines_), max(lines_)
        where = f"{first}" if first == last else f"{first}-{last}"
        out = [f"# constants ({escape(self.base)}:{where})"]
        for (py, value, _, _), d in zip(self.c.constants, self.c.grammar.defines, strict=True):
            line = f"{py} = {q(float(value))}"
            if not isinstance(d.expr, Num):
                line += f"  # {escape(d.text)}"
            out.append(noqa(line))
        return out

    def axiom_node(self) -> Successor:
        """The grammar's 'Axiom:' line (the checker refuses a grammar without one)."""
        axiom = self.c.grammar.axiom
        assert axiom is not None, "a checked grammar has an axiom"
        return axiom

    def locations(self) -> list[str]:
        """LOCATIONS: (line, col) of the axiom and of each production's and interpretation
        rule's first alternative; the runtime names them in its error messages."""
        c = self.c
        axiom = self.axiom_node()
        items = [f"{q('axiom')}: {q((axiom.line, axiom.col))}"]
        for kind, section in (("production", c.productions), ("interpretation", c.interpretation)):
            for pred, rs in section.items():
                first = min((a.rule.line, a.rule.col) for g in rs.groups for a in g.alts)
                items.append(f"{q(f'{kind} {pred}')}: {q(first)}")
        return ["LOCATIONS = {"] + [noqa(f"    {x},") for x in items] + ["}"]

    def program(self, prods: dict[str, str], interps: dict[str, str]) -> list[str]:
        c = self.c

        def mapping(key: str, d: dict[str, str]) -> list[str]:
            if not d:
                return [f"    {key}={{}},"]
            return [f"    {key}={{"] + [f"        {q(k)}: {v}," for k, v in d.items()] + ["    },"]

        vp = q(None if c.viewport is None else tuple(float(v) for v in c.viewport))
        lines = [
            "PROGRAM = Program(",
            f"    name={q(c.name)},",
            f"    source={q(self.source_path)},",
            f"    grammar_hash={q(self.grammar_hash)},",
            "    sites=SITES,",
            "    axiom=axiom,",
        ]
        lines += mapping("productions", prods) + mapping("interpretation", interps)
        lines += mapping("arity", {k: q(v) for k, v in c.arity.items()})
        lines += [
            f"    derivation_length={q(c.derivation_length)},",
            f"    angle={q(float(c.angle))},",
            f"    viewport={vp},",
            f"    start={q(tuple(float(v) for v in c.start))},",
            f"    max_primitives={q(c.max_primitives)},",
        ]
        if c.max_modules is not None:
            lines.append(f"    max_modules={q(c.max_modules)},")
        if c.dim == 3:  # 2D modules stay as they were before 3D
            lines.append("    dim=DIM,")
            if c.box is not None:
                lines.append(f"    box={q(tuple(float(v) for v in c.box))},")
            if c.tropism is not None:
                lines.append(f"    tropism={q(tuple(float(v) for v in c.tropism))},")
        lines += ["    locations=LOCATIONS,", ")"]
        return [noqa(x) for x in lines]

    def write(self) -> str:
        c = self.c
        body: list[str] = []
        axiom = self.axiom_node()
        body += ["", "", "def axiom(ctx):"]
        body += self.docstring([f"Axiom: {axiom.text}"], axiom.line, axiom.line, "    ")
        body += self.successor(c.axiom, ExprPrinter(c.const_names, c.call_sites), "    ")
        prods: dict[str, str] = {}
        interps: dict[str, str] = {}
        for section, prefix, table in (
            (c.productions, "produce_", prods),
            (c.interpretation, "interpret_", interps),
        ):
            for pred, rs in section.items():
                table[pred] = prefix + pred
                body += ["", ""] + self.function(prefix + pred, rs)
        sites = ["SITES = ["] + [x for s in c.sites for x in self.site(s)] + ["]"]
        if not c.sites:
            sites = ["SITES = []"]
        tail = ["", ""] + self.program(prods, interps)
        code = "\n".join(body + tail)
        head = [HEADER_START + escape(self.source_path) + HEADER_END, ""]
        if "math." in code:
            head += ["import math", ""]
        head.append("from ngpm_runtime.program import Program" + (", Site" if c.sites else ""))
        protocol = f"PROTOCOL = {q(PROTOCOL)}  # the runtime refuses a module of another protocol"
        head += ["", protocol]
        if c.dim == 3:
            head.append("DIM = 3  # a 3D grammar: the runtime's 3D turtle draws it")
        const = self.constants()
        head += [""] + (const + [""] if const else []) + sites + [""] + self.locations()
        return "\n".join(head) + "\n" + code + "\n"


def generate(checked: Checked, source_path: str, grammar_hash: str) -> str:
    """The Python source of the sampler module."""
    return ModuleWriter(checked, source_path, grammar_hash).write()
