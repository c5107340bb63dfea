"""A generated sampler's productions as numba source: the compiled deriver's grammar part.

`kernel_source(program)` reads the sampler module's own Python (`Program.code`, what
`ngpmc compile` wrote) and writes each production again as a function over arrays: the
module's parameters `par`, the replay values `vals[:nv]`, the successor rows `out` and the
request row `need`. A random call reads the next replay value, or fills `need` (site,
argument count, prior arguments) and returns NEED: the replay protocol of derive.py, in
the same order (a random call's arguments are evaluated before it, left to right).
`compiled.py` adds the generic derivation loop (the template there) and compiles the text.

An interpretation rule whose successors are one turtle symbol each (the `_lateK` rules of
`turtle arguments: lazy`) is written as a production that applies at any depth and whose
successor is never expanded (pushed at the derivation length): what derive.py does with it.
What it cannot write (a 2D grammar with other interpretation rules or polygons, a 3D grammar, a
random call that a short-circuit might skip, code of another shape) raises Unsupported:
the Python deriver then runs the grammar, as it runs every grammar in the tests' reference.
"""

from __future__ import annotations

import ast
from collections.abc import Collection
from dataclasses import dataclass, field

from ngpm_runtime.inference.sitekinds import KINDS
from ngpm_runtime.program import Program

# symbol codes of the derivation loop (compiled.TEMPLATE reads them)
IGNORE, CUT, HALT = 0, 1, 2
TURTLE_CODES = {
    "F": 10,
    "f": 11,
    "+": 12,
    "-": 13,
    "|": 14,
    "[": 15,
    "]": 16,
    "!": 17,
    "~l": 18,
    "@O": 19,
}
AXIOM_SYM = 0  # the axiom's pseudo-module
# produce() results besides a successor's length
NO_RULE, NEED = -1, -2

# math in generated code -> the kernel's function (CPython's errors kept: see compiled.py)
_MATH = {
    "sin": "_sin",
    "cos": "_cos",
    "tan": "_tan",
    "asin": "_asin",
    "acos": "_acos",
    "atan": "math.atan",
    "atan2": "math.atan2",
    "sqrt": "_sqrt",
    "exp": "_exp",
    "log": "_log",
    "pow": "_pow",
    "floor": "_floor",
    "ceil": "_ceil",
    "radians": "math.radians",
    "degrees": "math.degrees",
}
_BUILTINS = {"abs", "min", "max", "float", "bool"}
_RANDOM = {"normal", "uniform", "bernoulli", "categorical", "choose"}  # ReplayCtx's methods
_TUPLE_ARGS = {"categorical", "choose"}  # the methods given their weights as one tuple


class Unsupported(Exception):
    """The grammar needs something the compiled deriver does not do (its reason)."""


@dataclass
class KernelInfo:
    """What the derivation loop needs to know of the grammar besides the source."""

    symbols: dict[str, int] = field(default_factory=dict)  # name -> id (the axiom: 0)
    width: int = 3  # a stack row: symbol, depth, parameter count, parameters
    max_succ: int = 1  # the longest successor
    max_args: int = 1  # the most prior arguments of a random call
    late: set[str] = field(default_factory=set)  # interpretation rules run as productions


def kernel_source(program: Program) -> tuple[str, KernelInfo]:
    """The numba source of `program`'s productions (functions `produce` and the tables
    `PRODUCES`, `TCODE`) and what the loop needs of it; Unsupported when it cannot."""
    if program.dim != 2:
        raise Unsupported("a 3D grammar")
    code = program.code
    if not code:
        raise Unsupported("no generated source")
    tree = ast.parse(code)
    consts: dict[str, str] = {}
    funcs: dict[str, ast.FunctionDef] = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target = node.targets[0]
            if isinstance(target, ast.Name) and _is_number(node.value):
                consts[target.id] = ast.unparse(node.value)
        elif isinstance(node, ast.FunctionDef):
            funcs[node.name] = node
    info = KernelInfo()
    info.symbols["<axiom>"] = AXIOM_SYM
    prods = {"<axiom>": "axiom"}
    for name, fn in program.productions.items():
        prods[name] = fn.__name__
    for name, fn in program.interpretation.items():
        fdef = funcs.get(fn.__name__)
        if name in prods or fdef is None or not _one_symbol(fdef, program.interpretation):
            raise Unsupported("interpretation rules")
        prods[name] = fn.__name__
        info.late.add(name)
    writer = _Writer(info, consts)
    lines = ["# constants of the grammar"]
    lines += [f"c_{k} = {v}" for k, v in consts.items()]
    lines += [
        "",
        "",
        "@njit(cache=True, nogil=True)",
        "def produce(sym, par, n_par, vals, nv, out, need):",
        '    """The production of module `sym`: successor length, NO_RULE or NEED."""',
        "    k = 0",
        "    alt = 0",
    ]
    for name, fname in prods.items():
        fdef = funcs.get(fname)
        if fdef is None:
            raise Unsupported(f"no function {fname}")
        lines.append(f"    if sym == {writer.symbol(name)}:  # {fname}")
        lines += writer.function(fdef, "        ")
    lines.append(f"    return {NO_RULE}")
    lines += ["", "", _tables(prods, info), _site_tables(program)]
    info.width = 3 + max(writer.max_par, 2)
    info.max_succ = max(writer.max_succ, 1)
    info.max_args = max(writer.max_args, 1)
    return "\n".join(lines) + "\n", info


def _is_number(node: ast.expr) -> bool:
    if isinstance(node, ast.Constant):
        return isinstance(node.value, (int, float)) and not isinstance(node.value, bool)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        return _is_number(node.operand)
    if isinstance(node, ast.Call):  # float("inf")
        return (
            isinstance(node.func, ast.Name)
            and node.func.id == "float"
            and len(node.args) == 1
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        )
    return False


def _one_symbol(fdef: ast.FunctionDef, interpretation: Collection[str]) -> bool:
    """Every successor the rule returns is one turtle symbol the kernel draws, itself without
    an interpretation rule (then interpreting the rule's module is expanding it once)."""
    for node in ast.walk(fdef):
        if isinstance(node, ast.Return) and node.value is not None:
            v = node.value
            if isinstance(v, ast.Constant) and v.value is None:
                continue
            if not (isinstance(v, ast.List) and len(v.elts) == 1):
                return False
            head = v.elts[0]
            if not (
                isinstance(head, ast.Tuple)
                and head.elts
                and isinstance(head.elts[0], ast.Constant)
                and head.elts[0].value in TURTLE_CODES
                and head.elts[0].value not in interpretation
            ):
                return False
    return True


def _tables(prods: dict[str, str], info: KernelInfo) -> str:
    """PRODUCES per symbol: 0 none, 1 a production, 2 an interpretation rule run as one
    (at any depth, its successor pushed at the derivation length); TCODE its turtle code."""
    n = len(info.symbols)
    produces = [0] * n
    tcode = [IGNORE] * n
    for name, sym in info.symbols.items():
        produces[sym] = (2 if name in info.late else 1) if name in prods else 0
        if name in TURTLE_CODES:
            tcode[sym] = TURTLE_CODES[name]
        elif name == "%":
            tcode[sym] = CUT
        elif name == "halt":
            tcode[sym] = HALT
    return (
        f"PRODUCES = np.array({produces}, dtype=np.int64)\n"
        f"TCODE = np.array({tcode}, dtype=np.int64)\n"
        f"PUSH_SYM = {info.symbols.get('[', -1)}\n"
        f"POP_SYM = {info.symbols.get(']', -1)}"
    )


def _site_tables(program: Program) -> str:
    """Per site: its kind's code (sitekinds: normal 0, uniform 1, bernoulli 2, categorical
    3) and its prior argument count (the advance loop checks a request's arguments)."""
    kinds = [KINDS[s.kind].code for s in program.sites] or [0]
    n_args = [s.n_args() for s in program.sites] or [0]
    return (
        f"SITE_KIND = np.array({kinds}, dtype=np.int64)\n"
        f"SITE_NARGS = np.array({n_args}, dtype=np.int64)\n"
        f"N_SITES = {len(program.sites)}"
    )


class _Writer:
    """Writes production functions; collects symbols and the tables' sizes."""

    def __init__(self, info: KernelInfo, consts: dict[str, str]) -> None:
        self.info = info
        self.consts = consts
        self.max_par = 0
        self.max_succ = 0
        self.max_args = 0
        self.n_rand = 0

    def symbol(self, name: str) -> int:
        if name in ("{", ".", "}"):
            raise Unsupported("polygons")
        syms = self.info.symbols
        if name not in syms:
            syms[name] = len(syms)
        return syms[name]

    def function(self, fdef: ast.FunctionDef, ind: str) -> list[str]:
        """A production's body, for inside `produce` (at indent `ind`)."""
        params = [a.arg for a in fdef.args.args]
        if not params or params[0] != "ctx" or fdef.args.vararg or fdef.args.kwonlyargs:
            raise Unsupported(f"{fdef.name}: not a generated production")
        params = params[1:]
        self.max_par = max(self.max_par, len(params))
        # grammar names get a prefix: no clash with the kernel's own
        names = {p: f"p_{p}" for p in params}
        names.update({c: f"c_{c}" for c in self.consts if c not in names})
        names["alt"] = "alt"
        lines = [
            f"{ind}if n_par != {len(params)}:",
            f'{ind}    raise ValueError("{fdef.name}: wrong parameter count")',
        ]
        lines += [f"{ind}p_{p} = par[{i}]" for i, p in enumerate(params)]
        lines += self.block(fdef.body, names, ind)
        lines.append(f"{ind}return {NO_RULE}")
        return lines

    def block(self, body: list[ast.stmt], names: dict[str, str], ind: str) -> list[str]:
        out: list[str] = []
        for st in body:
            if isinstance(st, ast.Expr) and isinstance(st.value, ast.Constant):
                continue  # the docstring
            if isinstance(st, ast.Return):
                out += self.ret(st, names, ind)
            elif isinstance(st, ast.If) and not st.orelse:
                pre, test = self.expr(st.test, names, ind)
                out += pre + [f"{ind}if {test}:"]
                out += self.block(st.body, names, ind + "    ")
            elif (
                isinstance(st, ast.Assign)
                and len(st.targets) == 1
                and isinstance(st.targets[0], ast.Name)
                and st.targets[0].id == "alt"
            ):
                pre, value = self.expr(st.value, names, ind)
                out += pre + [f"{ind}alt = int({value})"]
            else:
                raise Unsupported(f"statement {ast.unparse(st)[:40]!r}")
        return out

    def ret(self, st: ast.Return, names: dict[str, str], ind: str) -> list[str]:
        v = st.value
        if v is None or (isinstance(v, ast.Constant) and v.value is None):
            return [f"{ind}return {NO_RULE}"]
        if not isinstance(v, ast.List):
            raise Unsupported("a production returns something else than a list")
        pre: list[str] = []
        rows: list[str] = []
        self.max_succ = max(self.max_succ, len(v.elts))
        for r, elt in enumerate(v.elts):
            if not (
                isinstance(elt, ast.Tuple)
                and elt.elts
                and isinstance(elt.elts[0], ast.Constant)
                and isinstance(elt.elts[0].value, str)
            ):
                raise Unsupported("a successor that is not a module tuple")
            sym = self.symbol(elt.elts[0].value)
            args = elt.elts[1:]
            self.max_par = max(self.max_par, len(args))
            rows.append(f"{ind}out[{r}, 0] = {sym}")
            rows.append(f"{ind}out[{r}, 2] = {len(args)}")
            for j, a in enumerate(args):
                p, text = self.expr(a, names, ind)
                pre += p
                rows.append(f"{ind}out[{r}, {3 + j}] = {text}")
        # the arguments are evaluated first (random calls in order), then written
        return pre + rows + [f"{ind}return {len(v.elts)}"]

    def expr(self, node: ast.expr, names: dict[str, str], ind: str) -> tuple[list[str], str]:
        """(statements that draw its random calls, in evaluation order; its text)."""
        pre: list[str] = []
        text = self._e(node, names, ind, pre, False)
        return pre, text

    def _e(
        self, node: ast.expr, names: dict[str, str], ind: str, pre: list[str], lazy: bool
    ) -> str:
        e = self._e
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
                raise Unsupported(f"constant {node.value!r}")
            return repr(node.value)
        if isinstance(node, ast.Name):
            if node.id not in names:
                raise Unsupported(f"name {node.id}")
            return names[node.id]
        if isinstance(node, ast.Attribute):
            if isinstance(node.value, ast.Name) and node.value.id == "math" and node.attr == "pi":
                return "math.pi"
            raise Unsupported(f"attribute {ast.unparse(node)}")
        if isinstance(node, ast.UnaryOp):
            op = {ast.USub: "-", ast.UAdd: "+", ast.Not: "not "}.get(type(node.op))
            if op is None:
                raise Unsupported("an operator")
            return f"({op}{e(node.operand, names, ind, pre, lazy)})"
        if isinstance(node, ast.BinOp):
            op = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Mod: "%"}.get(
                type(node.op)
            )
            if op is None:
                raise Unsupported("an operator")
            left = e(node.left, names, ind, pre, lazy)
            return f"({left} {op} {e(node.right, names, ind, pre, lazy)})"
        if isinstance(node, ast.Compare) and len(node.ops) == 1:
            ops = {
                ast.Lt: "<",
                ast.LtE: "<=",
                ast.Gt: ">",
                ast.GtE: ">=",
                ast.Eq: "==",
                ast.NotEq: "!=",
            }
            op = ops.get(type(node.ops[0]))
            if op is None:
                raise Unsupported("an operator")
            left = e(node.left, names, ind, pre, lazy)
            return f"({left} {op} {e(node.comparators[0], names, ind, pre, lazy)})"
        if isinstance(node, ast.BoolOp):
            op = " and " if isinstance(node.op, ast.And) else " or "
            first = e(node.values[0], names, ind, pre, lazy)
            rest = [e(v, names, ind, pre, True) for v in node.values[1:]]
            return "(" + op.join([first] + rest) + ")"
        if isinstance(node, ast.Call):
            return self._call(node, names, ind, pre, lazy)
        raise Unsupported(f"expression {ast.unparse(node)[:40]!r}")

    def _call(
        self, node: ast.Call, names: dict[str, str], ind: str, pre: list[str], lazy: bool
    ) -> str:
        f = node.func
        if node.keywords:
            raise Unsupported("keyword arguments")
        if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name):
            if f.value.id == "ctx" and f.attr in _RANDOM:
                if lazy:
                    raise Unsupported("a random call that a short-circuit may skip")
                return self._random(node, f.attr, names, ind, pre)
            if f.value.id == "math" and f.attr in _MATH:
                args = [self._e(a, names, ind, pre, lazy) for a in node.args]
                return f"{_MATH[f.attr]}({', '.join(args)})"
        if isinstance(f, ast.Name) and f.id in _BUILTINS:
            args = [self._e(a, names, ind, pre, lazy) for a in node.args]
            if f.id == "float" and len(args) == 1:
                return f"float({args[0]})"
            return f"{f.id}({', '.join(args)})"
        raise Unsupported(f"call {ast.unparse(node)[:40]!r}")

    def _random(
        self, node: ast.Call, method: str, names: dict[str, str], ind: str, pre: list[str]
    ) -> str:
        first = node.args[0] if node.args else None
        if not (isinstance(first, ast.Constant) and type(first.value) is int) or len(node.args) < 2:
            raise Unsupported("a random call without a site index")
        site = int(first.value)
        if method in _TUPLE_ARGS:
            if len(node.args) != 2 or not isinstance(node.args[1], ast.Tuple):
                raise Unsupported("weights that are not a tuple")
            arg_nodes = list(node.args[1].elts)
        else:
            arg_nodes = list(node.args[1:])
        args = [self._e(a, names, ind, pre, False) for a in arg_nodes]
        self.max_args = max(self.max_args, len(args))
        j = self.n_rand
        self.n_rand += 1
        pre.append(f"{ind}if k >= nv:")
        pre.append(f"{ind}    need[0] = {site}")
        pre.append(f"{ind}    need[1] = {len(args)}")
        pre += [f"{ind}    need[{2 + i}] = {a}" for i, a in enumerate(args)]
        pre.append(f"{ind}    return {NEED}")
        pre.append(f"{ind}r_{j} = vals[k]")
        pre.append(f"{ind}k += 1")
        return f"r_{j}"
