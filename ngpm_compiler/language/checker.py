"""Check a parsed grammar and build what codegen needs: constants, groups, sites, arities."""

from __future__ import annotations

import builtins
import keyword
import math
import re
from dataclasses import dataclass, field, replace

from ngpm_runtime.geometry.derive import MAX_PRIMITIVES, MAX_WORK
from ngpm_runtime.geometry.turtle import DRAWING
from ngpm_runtime.inference.sitekinds import KINDS
from ngpm_runtime.program import Site, prior_problem

from ngpm_compiler.language.errors import ErrorSink, GrammarError
from ngpm_compiler.language.expr import ExprPrinter
from ngpm_compiler.language.nodes import (
    Binary,
    Call,
    Expr,
    Grammar,
    ModuleUse,
    Node,
    Num,
    Rule,
    Successor,
    Unary,
    Var,
    walk,
)
from ngpm_compiler.language.tables import (
    BUILTIN_NAMES,
    FUNCTION_ARITY,
    RANDOM_CALLS,
    REWRITABLE_TURTLE,
    TURTLE,
    TURTLE_3D,
)

PROB_TOLERANCE = 1e-6
DEFAULT_DERIVATION_LENGTH = 1_000_000
DEFAULT_MAX_PRIMITIVES = 5000
# The largest value of each whole-number header (derive.py's ceilings on one sample's work).
HEADER_CEILINGS = {
    "derivation length": DEFAULT_DERIVATION_LENGTH,
    "max primitives": MAX_PRIMITIVES,
    "max modules": MAX_WORK,
}
# Python names a generated module defines or uses itself (l, O, I: ruff's E741), Python's
# keywords and builtins, and the forms of its generated names: a grammar name among them gets
# a prefix (`safe_name`), so no grammar name can shadow a name the generated code uses.
RESERVED = (
    {"math", "ctx", "alt", "Program", "Site", "SITES", "PROGRAM", "axiom", "l", "O", "I"}
    | set(keyword.kwlist)
    | set(dir(builtins))
    | {"copyright", "credits", "exit", "help", "license", "quit"}
)  # `site` adds these
GENERATED_NAME = re.compile(r"_|c_|p_|produce_|interpret_|arg\d+$")


@dataclass
class Resolved:
    """A successor module after name splitting, with every default argument filled in."""

    name: str
    args: list[Expr]
    use: ModuleUse


@dataclass
class Alt:
    rule: Rule
    modules: list[Resolved]
    prob: float | None


@dataclass
class Group:
    """Alternatives sharing a predecessor and a condition: one stochastic choice."""

    key: str  # site id prefix, e.g. "K(w>WMIN)" or "interp:L"
    cond: Expr | None
    rule: Rule  # the first rule: its parameter names and condition
    alts: list[Alt] = field(default_factory=list)
    site: int | None = None  # the `choose` site when there are several alternatives

    def probs(self) -> tuple[float, ...]:
        """The alternatives' probabilities (check_groups saw that each one has one)."""
        out = tuple(a.prob for a in self.alts if a.prob is not None)
        assert len(out) == len(self.alts), f"{self.key}: an alternative without a probability"
        return out


# A site found in the source: (line, col, 0 for a choice or 1 for a call), the site (index
# still -1: sites are numbered in source order once all are found), its group or call.
FoundSite = tuple[tuple[int, int, int], Site, Call | Group]


@dataclass
class RuleSet:
    """Every rule of one predecessor in one section (one generated function)."""

    pred: str
    section: str
    arity: int
    params: list[str]  # Python names of the function's parameters
    groups: list[Group] = field(default_factory=list)


@dataclass
class Checked:
    grammar: Grammar
    name: str
    constants: list[tuple[str, float, str, int]]  # python name, value, source text, line
    const_names: dict[str, str]  # grammar name -> python name
    axiom: list[Resolved]
    productions: dict[str, RuleSet]
    interpretation: dict[str, RuleSet]
    arity: dict[str, int]
    sites: list[Site]
    call_sites: dict[int, int]  # id(Call) -> site index
    derivation_length: int
    angle: float
    viewport: tuple[float, float, float, float] | None
    start: tuple[float, float, float]
    max_primitives: int
    max_modules: int | None = None  # 'max modules:' (None: the runtime's default)
    dim: int = 2  # 3: the grammar is 3D (`dimension`)
    box: tuple[float, ...] | None = None  # a 3D grammar's viewport: x, y and z ranges
    tropism: tuple[float, float, float, float] | None = None  # unit direction, elasticity
    # 'turtle arguments:' (None: no such line, eager) and the sites drawn (or, eager, that
    # would be drawn) where the turtle reaches them, after something their successor draws
    lazy: bool | None = None
    late_sites: list[int] = field(default_factory=list)


def safe_name(name: str, taken: set[str], prefix: str) -> str:
    """A Python identifier for a grammar name that shadows nothing the module uses: the name
    itself, or `prefix_name` (prefix `c` or `p`) when it is reserved or has the form of a
    generated name (then no other grammar name can give the same identifier)."""
    out = name if name not in RESERVED and not GENERATED_NAME.match(name) else f"{prefix}_{name}"
    while out in taken:
        out = f"{prefix}_{out}"
    return out


def shorten(text: str, more: bool, limit: int = 72) -> str:
    """One line of source for a site table: at most `limit` characters."""
    if more:
        text += " ..."
    return text if len(text) <= limit else text[: limit - 4].rstrip() + " ..."


def compact(text: str) -> str:
    return re.sub(r"\s+", "", text)


class Checker:
    def __init__(self, grammar: Grammar, name: str) -> None:
        self.g = grammar
        self.name = name
        self.sink = ErrorSink(grammar.filename, grammar.source)
        self.const_values: dict[str, float] = {}
        self.const_names: dict[str, str] = {}
        self.constants: list[tuple[str, float, str, int]] = []
        self.arity: dict[str, int] = {}
        self.arity_origin: dict[str, str] = {}

    def err(self, message: str, node: Node | tuple[int, int]) -> GrammarError:
        if isinstance(node, tuple):
            return self.sink.error(message, *node)
        return self.sink.error(message, node.line, node.col)

    # ---- constants -------------------------------------------------------------------------

    def evaluate(self, expr: Expr, what: str) -> float:
        """Value of a constant expression (already checked to use constants only)."""
        text = ExprPrinter(self.const_names).number(expr)
        env = {"math": math, **{self.const_names[k]: v for k, v in self.const_values.items()}}
        builtins = {"float": float, "bool": bool, "min": min, "max": max, "abs": abs}
        try:
            value = float(eval(text, {"__builtins__": builtins}, env))
        except ZeroDivisionError:
            raise self.err(f"division by zero in {what}", self.find_division(expr)) from None
        except (ValueError, OverflowError) as e:
            raise self.err(f"cannot evaluate {what}: {e}", expr) from None
        except (SyntaxError, RecursionError, MemoryError):
            raise self.err(f"{what} is nested too deeply for Python", expr) from None
        if not math.isfinite(value):
            raise self.err(f"{what} is not a finite number", expr)
        return value

    def find_division(self, expr: Expr) -> Node:
        for node in walk(expr):
            if isinstance(node, Binary) and node.op in ("/", "%"):
                try:
                    if self.evaluate(node.right, "divisor") == 0:
                        return node
                except GrammarError:
                    return node
        return expr

    def check_constants(self) -> None:
        taken: set[str] = set()
        for d in self.g.defines:
            if d.name in self.const_values:
                raise self.err(f"constant {d.name} is defined twice", d)
            if d.name in BUILTIN_NAMES:
                raise self.err(f"'{d.name}' is a built-in constant", d)
            self.check_expr(d.expr, {}, f"constant {d.name}", random_ok=False)
            value = self.evaluate(d.expr, f"constant {d.name}")
            py = safe_name(d.name, taken, "c")
            taken.add(py)
            self.const_names[d.name] = py
            self.const_values[d.name] = value
            self.constants.append((py, value, d.text, d.line))

    # ---- expressions -----------------------------------------------------------------------

    def check_expr(
        self, expr: Expr, params: dict[str, str], what: str, random_ok: bool, param_error: str = ""
    ) -> None:
        for node in walk(expr):
            if isinstance(node, Var):
                if node.name in params:
                    if param_error:
                        raise self.err(f"{param_error} (uses parameter {node.name})", node)
                elif node.name not in self.const_values and node.name not in BUILTIN_NAMES:
                    raise self.err(f"unknown identifier '{node.name}' in {what}", node)
            elif isinstance(node, Call):
                self.check_call(node, what, random_ok)

    def check_call(self, call: Call, what: str, random_ok: bool) -> None:
        if call.name in RANDOM_CALLS:
            if not random_ok:
                raise self.err(f"random call {call.name}() is not allowed in {what}", call)
            _, lo, hi = RANDOM_CALLS[call.name]
        elif call.name in FUNCTION_ARITY:
            lo, hi = FUNCTION_ARITY[call.name]
        else:
            raise self.err(f"unknown function '{call.name}'", call)
        n = len(call.args)
        if n < lo or (hi is not None and n > hi):
            want = str(lo) if lo == hi else (f"at least {lo}" if hi is None else f"{lo} to {hi}")
            raise self.err(
                f"{call.name}() takes {want} argument{'s' * (want != '1')}, got {n}", call
            )

    def is_constant(self, expr: Expr) -> bool:
        return all(
            not (
                isinstance(n, Var)
                and n.name not in self.const_values
                and n.name not in BUILTIN_NAMES
            )
            and not (isinstance(n, Call) and n.name in RANDOM_CALLS)
            for n in walk(expr)
        )

    def check_prior(self, call: Call) -> None:
        """Reject constant prior arguments no distribution accepts (the run-time rules of
        `prior_problem`, and no degenerate sd == 0 or a == b)."""
        if not all(self.is_constant(a) for a in call.args):
            return
        vals = tuple(self.evaluate(a, f"argument of {call.name}()") for a in call.args)
        bad = prior_problem(RANDOM_CALLS[call.name][0], vals, constant=True)
        if bad:
            raise self.err(f"{call.name}(): {bad}", call)

    # ---- modules ---------------------------------------------------------------------------

    def use_arity(self, name: str, n: int, where: Node) -> None:
        if name in TURTLE:
            lo, hi, _ = TURTLE[name]
            if not lo <= n <= hi:
                want = str(lo) if lo == hi else f"{lo} to {hi}"
                raise self.err(
                    f"turtle symbol {name} takes {want} argument{'s' * (want != '1')}, got {n}",
                    where,
                )
            return
        if name not in self.arity:
            self.arity[name] = n
            self.arity_origin[name] = f"line {where.line}"
        elif self.arity[name] != n:
            raise self.err(
                f"module {name} takes {self.arity[name]} argument"
                f"{'s' * (self.arity[name] != 1)} ({self.arity_origin[name]}), "
                f"got {n}",
                where,
            )

    def resolve(
        self, modules: list[ModuleUse], params: dict[str, str], what: str, known: set[str]
    ) -> list[Resolved]:
        out: list[Resolved] = []
        for use in modules:
            for part in self.split(use, known):
                self.check_symbol(part)
                for arg in part.args:
                    self.check_expr(arg, params, what, random_ok=True)
                self.use_arity(part.name, len(part.args), part)
                out.append(Resolved(part.name, part.args + self.defaults(part), part))
        self.check_brackets(out, what)
        return out

    def check_brackets(self, modules: list[Resolved], what: str) -> None:
        """Each `]` closes a `[` of the same successor, and each `[` is closed in it (the
        turtle would otherwise pop an empty stack at run time); each `}` closes a `{` of the
        same successor (a `{` left open draws nothing, which is no error)."""
        opened: list[Resolved] = []
        polygons = 0
        for m in modules:
            if m.name == "[":
                opened.append(m)
            elif m.name == "]":
                if not opened:
                    raise self.err(f"unmatched ']' in {what}: no '[' before it", m.use)
                opened.pop()
            elif m.name == "{":
                polygons += 1
            elif m.name == "}":
                if not polygons:
                    raise self.err(f"unmatched '}}' in {what}: no '{{' before it", m.use)
                polygons -= 1
        if opened:
            raise self.err(f"unmatched '[' in {what}: no ']' closes it", opened[-1].use)

    def split(self, use: ModuleUse, known: set[str]) -> list[ModuleUse]:
        """`FF` is `F F` when it is not a module itself and each letter is a known module."""
        name = use.name
        if (
            len(name) > 1
            and name.isalpha()
            and name not in known
            and name not in TURTLE
            and all(c in known for c in name)
        ):
            parts = [ModuleUse(use.line, use.col + i, c, []) for i, c in enumerate(name)]
            parts[-1].args, parts[-1].explicit_args = use.args, use.explicit_args
            return parts
        return [use]

    def check_symbol(self, use: ModuleUse) -> None:
        if use.name[:1] == "~" and use.name != "~l":
            raise self.err(f"unsupported symbol '{use.name}': the only surface is ~l (leaf)", use)
        if use.name[:1] == "@" and use.name not in TURTLE:
            raise self.err(
                f"unsupported symbol '{use.name}': the @ symbols are @O (disk or "
                "sphere), @Tp and @Ts (3D tropism)",
                use,
            )

    def defaults(self, use: ModuleUse) -> list[Expr]:
        if use.name not in TURTLE:
            return []
        lo, hi, defaults = TURTLE[use.name]
        fill = defaults[len(use.args) - lo :] if len(use.args) < hi else ()
        return [Num(use.line, use.col, self.angle if d == "angle" else float(d)) for d in fill]

    # ---- headers ---------------------------------------------------------------------------

    def headers(self) -> None:
        h = self.g.headers
        values: dict[str, list[float]] = {}
        self.lazy = False
        for kind, header in h.items():
            if kind == "turtle arguments":
                self.lazy = self.laziness(header.values[0])
                continue
            for v in header.values:
                self.check_expr(v, {}, f"'{kind}:'", random_ok=False)
            values[kind] = [self.evaluate(v, f"'{kind}:'") for v in header.values]
        self.angle = values.get("angle", [90.0])[0]
        self.viewport = None
        if "viewport" in values:
            vp = values["viewport"]
            if not all(lo < hi for lo, hi in zip(vp[0::2], vp[1::2], strict=True)):
                raise self.err(
                    "viewport needs xmin < xmax and ymin < ymax"
                    + " and zmin < zmax" * (len(vp) == 6),
                    h["viewport"],
                )
            self.viewport = tuple(vp)
        self.tropism = None
        if "tropism" in values:
            tx, ty, tz, e = values["tropism"]
            norm = math.sqrt(tx * tx + ty * ty + tz * tz)
            if norm == 0:
                raise self.err("'tropism:' needs a direction other than 0 0 0", h["tropism"])
            self.tropism = (tx / norm, ty / norm, tz / norm, e)
        self.dims = None
        if "dimensions" in values:
            self.dims = values["dimensions"][0]
            if self.dims not in (2, 3):
                raise self.err(
                    f"'dimensions:' must be 2 or 3, got {self.dims:g}", h["dimensions"].values[0]
                )
        x, y, heading = values.get("start", [0.0, 0.0, 90.0])  # lsys.lark: three values
        self.start = (x, y, heading)
        self.derivation_length = self.integer(
            values, "derivation length", 0, DEFAULT_DERIVATION_LENGTH
        )
        self.max_primitives = self.integer(values, "max primitives", 1, DEFAULT_MAX_PRIMITIVES)
        self.max_modules = (
            self.integer(values, "max modules", 1, 0) if "max modules" in values else None
        )

    def laziness(self, value: Expr) -> bool:
        """'turtle arguments: lazy' (True) or 'eager' (False, the default)."""
        word = value.name.lower() if isinstance(value, Var) else ""
        if word not in ("lazy", "eager"):
            shown = value.name if isinstance(value, Var) else "a number"
            raise self.err(f"'turtle arguments:' is lazy or eager, got {shown}", value)
        return word == "lazy"

    def integer(self, values: dict[str, list[float]], kind: str, least: int, default: int) -> int:
        """A whole-number header's value, at least `least` and at most its ceiling."""
        if kind not in values:
            return default
        v = values[kind][0]
        where = self.g.headers[kind].values[0]
        if v != int(v) or v < least:
            raise self.err(f"'{kind}:' must be an integer >= {least}, got {v:g}", where)
        if v > HEADER_CEILINGS[kind]:
            raise self.err(
                f"'{kind}:' must be at most {HEADER_CEILINGS[kind]}, got {v:g} "
                "(ngpm's ceiling on the work one sample may do)",
                where,
            )
        return int(v)

    # ---- rules -----------------------------------------------------------------------------

    def declarations(self) -> None:
        for d in self.g.decls:
            if d.name in TURTLE:
                raise self.err(f"{d.name} is a turtle symbol, it cannot be declared", d)
            if len(set(d.params)) != len(d.params):
                raise self.err(f"duplicate parameter in module {d.name}", d)
            self.use_arity(d.name, len(d.params), d)

    def rule_sets(self, section: str, known: set[str]) -> dict[str, RuleSet]:
        sets: dict[str, RuleSet] = {}
        by_key: dict[tuple[str, str], Group] = {}
        for rule in (r for r in self.g.rules if r.section == section):
            self.check_params(rule)
            arity = len(rule.params)
            if rule.pred in TURTLE and rule.pred not in REWRITABLE_TURTLE:
                raise self.err(f"turtle symbol {rule.pred} cannot be rewritten", rule)
            if rule.pred in TURTLE:
                self.use_arity(rule.pred, arity, rule)
                arity = TURTLE[rule.pred][1]
            else:
                self.use_arity(rule.pred, arity, rule)
            params = {p: p for p in rule.params}
            if rule.pred not in sets:
                taken = set(self.const_names.values())
                py = []
                for p in rule.params:
                    py.append(safe_name(p, taken, "p"))
                    taken.add(py[-1])
                py += [f"arg{i}" for i in range(len(py), arity)]
                sets[rule.pred] = RuleSet(rule.pred, section, arity, py)
            rs = sets[rule.pred]
            where = f"rule for {rule.pred}"
            if rule.cond is not None:
                self.check_expr(rule.cond, params, f"the condition of {rule.pred}", random_ok=False)
            canon = canonical(rule.cond, rule.params) if rule.cond is not None else ""
            group = by_key.get((rule.pred, canon))
            if group is None:
                if rs.groups and rs.groups[-1].cond is None:
                    raise self.err(
                        f"this rule never applies: an earlier rule for {rule.pred} "
                        "has no condition",
                        rule,
                    )
                prefix = ("interp:" if section == "interpretation" else "") + rule.pred
                if rule.cond is not None:
                    prefix += f"({compact(rule.cond_text)})"
                group = Group(prefix, rule.cond, rule)
                by_key[(rule.pred, canon)] = group
                rs.groups.append(group)
            prob = None
            if rule.prob is not None:
                self.check_expr(
                    rule.prob,
                    params,
                    f"the probability of {rule.pred}",
                    random_ok=False,
                    param_error="a probability must be a constant expression",
                )
                prob = self.evaluate(rule.prob, "probability")
                if not 0 <= prob <= 1:
                    raise self.err(f"probability {prob:g} is not in [0, 1]", rule.prob)
            mods = self.resolve(rule.successor.modules, params, where, known)
            group.alts.append(Alt(rule, mods, prob))
        return sets

    def check_params(self, rule: Rule) -> None:
        seen: set[str] = set()
        for p, where in zip(rule.params, rule.param_pos, strict=True):
            if p in seen:
                raise self.err(f"duplicate parameter '{p}' in {rule.pred}", where)
            seen.add(p)

    def check_groups(self, sets: dict[str, RuleSet]) -> None:
        for rs in sets.values():
            for group in rs.groups:
                alts = group.alts
                probs = [a.prob for a in alts]
                if len(alts) > 1 and any(p is None for p in probs):
                    bad = next(a for a in alts if a.prob is None).rule
                    cond = f" with condition {group.rule.cond_text}" if group.cond else ""
                    raise self.err(
                        f"{rs.pred}{cond} has {len(alts)} alternatives: each needs a "
                        "probability (': p')",
                        bad,
                    )
                if any(p is not None for p in probs):
                    total = sum(p for p in probs if p is not None)
                    if abs(total - 1.0) > PROB_TOLERANCE:
                        raise self.err(
                            f"the probabilities of {group.key} sum to {total:g}, not 1",
                            alts[0].rule.prob or alts[0].rule,
                        )

    def check_recursion(self, sets: dict[str, RuleSet]) -> None:
        if "derivation length" in self.g.headers:
            return
        edges = {
            p: {m.name for g in rs.groups for a in g.alts for m in a.modules if m.name in sets}
            for p, rs in sets.items()
        }
        state: dict[str, int] = {}
        path: list[str] = []

        def visit(node: str) -> list[str] | None:
            state[node] = 1
            path.append(node)
            for nxt in sorted(edges[node]):
                if state.get(nxt) == 1:
                    return path[path.index(nxt) :] + [nxt]
                if nxt not in state:
                    found = visit(nxt)
                    if found:
                        return found
            path.pop()
            state[node] = 2
            return None

        for pred in sets:
            if pred not in state:
                cycle = visit(pred)
                if cycle:
                    first = sets[cycle[0]].groups[0].rule
                    raise self.err(
                        "recursive rules (" + " -> ".join(cycle) + ") need a "
                        "'derivation length:' line",
                        first,
                    )

    # ---- sites -----------------------------------------------------------------------------

    def collect_sites(self, axiom: list[Resolved], sets: list[dict[str, RuleSet]]) -> None:
        """Number every random call and every stochastic group, in source order."""
        found: list[FoundSite] = []
        self.add_calls(found, "axiom", "axiom", 0, axiom)
        for section in sets:
            for rs in section.values():
                for group in rs.groups:
                    if len(group.alts) > 1:
                        r = group.rule
                        texts = list(dict.fromkeys(a.rule.text for a in group.alts))
                        source = shorten(" ".join(texts[0].split()), len(texts) > 1)
                        found.append(
                            (
                                (r.line, r.col, 0),
                                Site(
                                    index=-1,
                                    id=f"{group.key}/choice",
                                    kind="categorical",
                                    k=len(group.alts),
                                    probs=group.probs(),
                                    name=f"choice of {rs.pred}",
                                    module=rs.pred,
                                    arity=rs.arity,
                                    line=r.line,
                                    col=r.col,
                                    source=source,
                                ),
                                group,
                            )
                        )
                    for i, alt in enumerate(group.alts):
                        self.add_calls(found, f"{group.key}/{i}", rs.pred, rs.arity, alt.modules)
        found.sort(key=lambda f: f[0])
        self.sites: list[Site] = []
        self.call_sites: dict[int, int] = {}
        for index, (_, site, owner) in enumerate(found):
            self.sites.append(replace(site, index=index))
            if isinstance(owner, Call):
                self.call_sites[id(owner)] = index
            elif isinstance(owner, Group):
                owner.site = index

    def add_calls(
        self, found: list[FoundSite], prefix: str, module: str, arity: int, mods: list[Resolved]
    ) -> None:
        counts: dict[str, int] = {}
        for m in mods:
            for arg in m.args:
                for node in walk(arg):
                    if isinstance(node, Call) and node.name in RANDOM_CALLS:
                        self.check_prior(node)
                        kind = RANDOM_CALLS[node.name][0]
                        n = counts.get(kind, 0)
                        counts[kind] = n + 1
                        found.append(
                            (
                                (node.line, node.col, 1),
                                Site(
                                    index=-1,
                                    id=f"{prefix}/{kind}{n}",
                                    kind=kind,
                                    k=len(node.args) if KINDS[kind].weighted else 2,
                                    name=shorten(f"{node.text} in {module}", False),
                                    module=module,
                                    arity=arity,
                                    line=node.line,
                                    col=node.col,
                                    source=shorten(node.text, False),
                                ),
                                node,
                            )
                        )

    # ---- lazy turtle arguments -------------------------------------------------------------

    def defer(
        self, axiom: list[Resolved], sets: list[dict[str, RuleSet]], known: set[str]
    ) -> tuple[list[Resolved], list[int]]:
        """'turtle arguments: lazy': a turtle symbol with a random argument after anything but
        `[` in its successor becomes a module of its own (`_lateK`, the enclosing rule's parameters
        passed on) whose interpretation rule is the symbol, so its sites are sampled when the
        turtle reaches it, where a guide sees the turtle and what was drawn before. The
        distribution of samples is the same; each site keeps its id and number. Symbols a
        production rewrites (F, f) stay. Returns the axiom and the numbers of the sites that
        are (or, eager, would be) drawn late after something their successor draws (or a
        module that may draw); adds the rules to the interpretation set (sets[1]) when the
        grammar says lazy."""
        productions, interpretation = sets
        taken = set(known) | set(self.arity) | set(productions) | set(interpretation)
        made: list[RuleSet] = []
        late_sites: list[int] = []

        def new_name() -> str:
            name = f"_late{len(made) + 1}"
            while name in taken:
                name += "_"
            taken.add(name)
            return name

        def late(mods: list[Resolved], rule: Rule | None, py: list[str]) -> list[Resolved]:
            out: list[Resolved] = []
            for m in mods:
                if all(o.name == "[" for o in out):  # the turtle is where the rule fired
                    out.append(m)
                    continue
                calls = [
                    n
                    for a in m.args
                    for n in walk(a)
                    if isinstance(n, Call) and n.name in RANDOM_CALLS
                ]
                if m.name not in TURTLE or m.name in productions or not calls:
                    out.append(m)
                    continue
                if any(o.name in DRAWING or o.name not in TURTLE for o in out):
                    # after something that draws (or may): worth a hint
                    late_sites.extend(self.call_sites[id(n)] for n in calls)
                if not self.lazy:
                    out.append(m)
                    continue
                params = list(rule.params) if rule is not None else []
                made.append(self.late_rule(m, new_name(), params, py[: len(params)]))
                args: list[Expr] = [Var(m.use.line, m.use.col, p) for p in params]
                name = made[-1].pred
                out.append(Resolved(name, args, ModuleUse(m.use.line, m.use.col, name, args)))
            return out

        for section in sets:
            for rs in list(section.values()):
                for group in rs.groups:
                    for alt in group.alts:
                        alt.modules = late(alt.modules, alt.rule, rs.params)
        axiom = late(axiom, None, [])
        for rs in made:
            interpretation[rs.pred] = rs
        return axiom, sorted(late_sites)

    def late_rule(self, m: Resolved, name: str, params: list[str], py: list[str]) -> RuleSet:
        """The interpretation rule `name(params) --> m` of a symbol drawn late."""
        line, col = m.use.line, m.use.col
        text = f"{m.use.name} at line {line}:{col}, sampled where the turtle reaches it"
        syn = Rule(
            line, col, name, params, [(line, col)] * len(params), None, "",
            Successor(line, col, [m.use], text), None, "interpretation", text, line,
        )  # fmt: skip
        rs = RuleSet(name, "interpretation", len(params), py)
        rs.groups.append(Group(f"interp:{name}", None, syn, [Alt(syn, [m], None)]))
        self.arity[name] = len(params)
        return rs

    # ---- dimension -------------------------------------------------------------------------

    def dimension(self, axiom: list[Resolved], sets: list[dict[str, RuleSet]]) -> int:
        """3 when the grammar says so ('dimensions: 3') or uses anything only 3D has: a 3D
        turtle symbol, a 'tropism:' line or a viewport of 6 numbers; else 2. A 3D grammar's
        viewport is a box (6 numbers)."""
        uses = [m.use for m in axiom if m.name in TURTLE_3D]
        uses += [
            m.use
            for section in sets
            for rs in section.values()
            for g in rs.groups
            for a in g.alts
            for m in a.modules
            if m.name in TURTLE_3D
        ]
        signs: list[tuple[Node, str]] = []
        if uses:
            first = min(uses, key=lambda u: (u.line, u.col))
            signs.append((first, f"the 3D symbol '{first.name}'"))
        h = self.g.headers
        if "tropism" in h:
            signs.append((h["tropism"], "'tropism:'"))
        if self.viewport is not None and len(self.viewport) == 6:
            signs.append((h["viewport"], "a viewport of 6 numbers (a 3D box)"))
        if self.dims == 2 and signs:
            node, what = min(signs, key=lambda s: (s[0].line, s[0].col))
            raise self.err(
                f"{what} needs a 3D grammar, but 'dimensions: 2' says this one is 2D", node
            )
        dim = 3 if signs or self.dims == 3 else 2
        if dim == 3 and self.viewport is not None and len(self.viewport) != 6:
            node, what = (
                min(signs, key=lambda s: (s[0].line, s[0].col))
                if signs
                else (h["dimensions"], "'dimensions: 3'")
            )
            raise self.err(
                f"this grammar is 3D ({what} at line {node.line}:{node.col}), so its "
                "viewport is a box of 6 numbers: xmin xmax ymin ymax zmin zmax",
                h["viewport"],
            )
        return dim

    # ---- all -------------------------------------------------------------------------------

    def run(self) -> Checked:
        self.check_constants()
        self.headers()
        self.declarations()
        known = {d.name for d in self.g.decls} | {r.pred for r in self.g.rules} | REWRITABLE_TURTLE
        if self.g.axiom is None:
            raise self.err("the grammar has no 'Axiom:' line", (1, 1))
        axiom = self.resolve(self.g.axiom.modules, {}, "the axiom", known)
        productions = self.rule_sets("production", known)
        interpretation = self.rule_sets("interpretation", known)
        self.check_groups(productions)
        self.check_groups(interpretation)
        self.check_recursion(productions)
        self.collect_sites(axiom, [productions, interpretation])
        axiom, late_sites = self.defer(axiom, [productions, interpretation], known)
        dim = self.dimension(axiom, [productions, interpretation])
        box = self.viewport if dim == 3 else None
        vp = self.viewport
        viewport = (vp[0], vp[1], vp[2], vp[3]) if vp is not None else None  # x and y ranges
        return Checked(
            self.g,
            self.name,
            self.constants,
            self.const_names,
            axiom,
            productions,
            interpretation,
            dict(self.arity),
            self.sites,
            self.call_sites,
            self.derivation_length,
            self.angle,
            viewport,
            self.start,
            self.max_primitives,
            max_modules=self.max_modules,
            dim=dim,
            box=box,
            tropism=self.tropism,
            lazy=self.lazy if "turtle arguments" in self.g.headers else None,
            late_sites=late_sites,
        )


def canonical(expr: Expr, params: list[str]) -> str:
    """A condition's structure with parameters numbered, so `x > 1` in A(x) and `y > 1` in
    A(y) are the same condition."""
    if isinstance(expr, Num):
        return repr(expr.value)
    if isinstance(expr, Var):
        return f"${params.index(expr.name)}" if expr.name in params else expr.name
    if isinstance(expr, Unary):
        return f"({expr.op} {canonical(expr.operand, params)})"
    if isinstance(expr, Binary):
        return f"({canonical(expr.left, params)} {expr.op} {canonical(expr.right, params)})"
    return f"{expr.name}(" + ", ".join(canonical(a, params) for a in expr.args) + ")"


def check(grammar: Grammar, name: str) -> Checked:
    """Check a parsed grammar; raise GrammarError at the first problem."""
    return Checker(grammar, name).run()
