"""Sequential derivation of one particle (architecture.md sections 2 and 3).

A particle holds a persistent stack of pending modules, leftmost on top. `Deriver.advance`
pops modules until the particle draws a primitive (a resampling point), needs a random value
(it then waits with `need = (site, prior args)`; SMC draws the value for all waiting particles
at once and appends it to `values`), finishes, or hits a cap. Productions are replayed with
the values chosen so far, so no generator is ever copied.

Stack nodes are flat tuples `(module, depth, ilevel, rest)`: `ilevel` 0 means a module of the
derivation; `ilevel` > 0 a module produced by interpretation rules at that nesting level
(interpreted only, never expanded).
"""

from __future__ import annotations

import re
from collections.abc import Callable

from ngpm_runtime.errors import ProgramError
from ngpm_runtime.program import Program
from ngpm_runtime.turtle import CUT, HALT, TURTLE_SYMBOLS, interpret

MAX_INTERP_DEPTH = 64
DEFAULT_MAX_OPS = 2_000_000  # modules popped by one particle in one step before "limit"

# advance() outcomes
DRAWN, NEED, DONE, LIMIT = 1, 2, 3, 4

_LOC = re.compile(r"\(([^()\s]+\.lsys):(\d+)(?:-\d+)?\)\s*$")


class NeedSite(BaseException):  # noqa: N818 - a request, not an error
    """Raised by the replay context when a production asks for a value not chosen yet.
    A BaseException so that no `except Exception` in generated code can swallow it."""

    def __init__(self, site: int, args: tuple) -> None:
        self.site = site
        self.args = args


class ReplayCtx:
    """The `ctx` a production receives: answers from the values already chosen."""

    __slots__ = ("values", "sites", "pos")

    def __init__(self) -> None:
        self.values: list[float] = []
        self.sites: list[int] = []
        self.pos = 0

    def _next(self, site: int, args: tuple) -> float:
        pos = self.pos
        if pos < len(self.values):
            if self.sites[pos] != site:
                raise ProgramError(
                    f"generated code is not pure: replay asked for site {site}, "
                    f"recorded site {self.sites[pos]}"
                )
            self.pos = pos + 1
            return self.values[pos]
        raise NeedSite(site, args)

    def normal(self, site: int, mu: float, sigma: float) -> float:
        return self._next(site, (mu, sigma))

    def uniform(self, site: int, a: float, b: float) -> float:
        return self._next(site, (a, b))

    def bernoulli(self, site: int, p: float) -> float:
        return self._next(site, (p,))

    def categorical(self, site: int, weights: tuple) -> float:
        return self._next(site, tuple(weights))

    def choose(self, site: int, probs: tuple) -> int:
        return int(self._next(site, tuple(probs)))


class Particle:
    """One particle's plain state. Shared parts are immutable, so `copy` is shallow."""

    __slots__ = (
        "stack", "turtle", "tstack", "poly", "prims", "n_prims", "trace",
        "values", "sites", "need", "in_interp", "last", "status",
    )

    def __init__(self, stack: tuple | None, turtle: tuple) -> None:
        self.stack = stack
        self.turtle = turtle
        self.tstack: tuple | None = None
        self.poly: tuple | None = None
        self.prims: tuple | None = None  # cons list, newest first
        self.n_prims = 0
        self.trace: tuple | None = None  # cons list of (site, features, value)
        self.values: list[float] = []  # replay values for the module on top of the stack
        self.sites: list[int] = []
        self.need: tuple[int, tuple] | None = None
        self.in_interp = False  # the top module's production returned None
        self.last: tuple | None = None  # primitive drawn by the last step
        self.status = "live"

    def copy(self) -> Particle:
        q = Particle.__new__(Particle)
        for name in Particle.__slots__:
            setattr(q, name, getattr(self, name))
        q.values = list(self.values)
        q.sites = list(self.sites)
        return q


def _where(fn: Callable, kind: str, mod: tuple) -> str:
    """'vines.lsys:24: production B' from the generated function's docstring."""
    m = _LOC.search((fn.__doc__ or "").strip().splitlines()[-1] if fn.__doc__ else "")
    loc = f"{m.group(1)}:{m.group(2)}: " if m else ""
    return f"{loc}{kind} {mod[0]}{tuple(mod[1:]) if len(mod) > 1 else ''}"


class Deriver:
    """Steps particles of one program. Holds the program's lookup tables and one ctx."""

    def __init__(self, program: Program, max_ops: int = DEFAULT_MAX_OPS) -> None:
        self.program = program
        self.prods = dict(program.productions)
        self.interp = dict(program.interpretation)
        self.dlen = program.derivation_length
        self.angle = float(program.angle)
        self.max_ops = max_ops
        self.ctx = ReplayCtx()

    def start(self, turtle: tuple) -> Particle:
        """A new particle at `turtle` = (x, y, heading, width), axiom modules at depth 0.
        The axiom may itself draw random values: it runs as the pseudo-module `axiom`."""
        stack = (("axiom",), -1, 0, None)
        return Particle(stack, turtle)

    def _call(self, p: Particle, fn: Callable, kind: str, mod: tuple) -> list | None:
        ctx = self.ctx
        ctx.values = p.values
        ctx.sites = p.sites
        ctx.pos = 0
        try:
            succ = fn(ctx, *mod[1:]) if kind != "axiom" else fn(ctx)
        except NeedSite:
            raise
        except ProgramError as err:
            raise ProgramError(f"{_where(fn, kind, mod)}: {err}") from None
        except RecursionError:
            raise ProgramError(f"{_where(fn, kind, mod)}: runaway recursion") from None
        except Exception as err:
            raise ProgramError(
                f"{_where(fn, kind, mod)}: {type(err).__name__}: {err}"
            ) from None
        if succ is not None and not isinstance(succ, list | tuple):
            raise ProgramError(f"{_where(fn, kind, mod)}: returned {type(succ).__name__}, "
                               "not a list of modules")
        return succ

    def advance(self, p: Particle) -> int:
        """Run `p` to its next resampling point; returns DRAWN, NEED, DONE or LIMIT."""
        prods, interp, dlen = self.prods, self.interp, self.dlen
        stack = p.stack
        turtle, tstack, poly = p.turtle, p.tstack, p.poly
        ops = 0
        try:
            while stack is not None:
                ops += 1
                if ops > self.max_ops:
                    p.stack, p.turtle, p.tstack, p.poly = stack, turtle, tstack, poly
                    return LIMIT
                mod, depth, ilevel, rest = stack
                name = mod[0]
                if depth < 0:  # the axiom pseudo-module
                    succ = self._call(p, self.program.axiom, "axiom", mod)
                    stack = _push(succ or [], 0, 0, rest, "axiom")
                    p.values, p.sites = [], []
                    continue
                if ilevel == 0 and not p.in_interp and depth < dlen:
                    fn = prods.get(name)
                    if fn is not None:
                        succ = self._call(p, fn, "production", mod)
                        p.values, p.sites = [], []
                        if succ is not None:
                            stack = _push(succ, depth + 1, 0, rest, name)
                            continue
                fn = interp.get(name)
                if fn is not None:
                    if ilevel >= MAX_INTERP_DEPTH:
                        raise ProgramError(
                            f"interpretation rules recurse deeper than {MAX_INTERP_DEPTH} "
                            f"levels (at module {name})"
                        )
                    p.in_interp = True
                    succ = self._call(p, fn, "interpretation", mod)
                    p.values, p.sites = [], []
                    p.in_interp = False
                    if succ is not None:
                        stack = _push(succ, depth, ilevel + 1, rest, name)
                        continue
                p.in_interp = False
                stack = rest
                if name in TURTLE_SYMBOLS:
                    turtle, tstack, poly, prim = interpret(mod, turtle, tstack, poly, self.angle)
                    if prim is not None:
                        p.stack, p.turtle, p.tstack, p.poly = stack, turtle, tstack, poly
                        p.last = prim
                        p.prims = (prim, p.prims)
                        p.n_prims += 1
                        return DRAWN
                elif name == CUT:
                    stack = _cut(stack)
                elif name == HALT:
                    stack = None
        except NeedSite as need:
            p.stack, p.turtle, p.tstack, p.poly = stack, turtle, tstack, poly
            p.need = (need.site, need.args)
            return NEED
        except (TypeError, ValueError, IndexError) as err:  # malformed turtle arguments
            raise ProgramError(f"turtle: bad module {mod!r}: {err}") from None
        p.stack, p.turtle, p.tstack, p.poly = None, turtle, tstack, poly
        return DONE


def _push(succ: list | tuple, depth: int, ilevel: int, rest: tuple | None, who: str):
    """Push a successor (leftmost on top) onto the stack `rest`."""
    for m in reversed(succ):
        if type(m) is not tuple or not m or type(m[0]) is not str:
            raise ProgramError(f"successor of {who}: {m!r} is not a module tuple")
        rest = (m, depth, ilevel, rest)
    return rest


def _cut(stack: tuple | None) -> tuple | None:
    """Discard pending modules up to (not including) the `]` closing the current branch."""
    level = 0
    node = stack
    while node is not None:
        n = node[0][0]
        if n == "[":
            level += 1
        elif n == "]":
            if level == 0:
                return node
            level -= 1
        node = node[3]
    return None
