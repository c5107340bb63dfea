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

from collections.abc import Callable, Iterable
from typing import Any

from ngpm_runtime.errors import ProgramError, printable
from ngpm_runtime.geometry.cons import Cons
from ngpm_runtime.geometry.turtle import CUT, DRAWING, HALT, TURTLE_OPS, Prim, Turtle
from ngpm_runtime.geometry.turtle3d import TURTLE3D_OPS, Turtle3, start3d
from ngpm_runtime.program import Module, Program, prior_problem

MAX_INTERP_DEPTH = 64
# The "max modules" cap: modules one particle may pop (expand or interpret) in one step, that
# is, between two drawn primitives, before it stops with status "limit". It bounds the work
# of grammars that expand without drawing (`A --> A A`). Grammar header `max modules:`, run
# option `--max-modules`, `smc(..., max_modules=)`.
DEFAULT_MAX_MODULES = 20_000  # the bundled grammars pop fewer than 30 per step
# Hard ceilings on one particle's whole derivation, whatever the grammar's headers or the run's
# options say: modules expanded or interpreted, and primitives drawn. Past one, the run stops
# with a ProgramError. The bundled vines pops fewer than 30 modules per primitive.
MAX_WORK = 10_000_000
MAX_PRIMITIVES = 100_000

# advance() outcomes
DRAWN, NEED, DONE, LIMIT = 1, 2, 3, 4

# dispatch codes per module name (a turtle symbol that may draw: _DRAW, a resampling point)
_IGNORE, _PROD, _INTERP, _CUT, _HALT, _TURTLE, _DRAW = 0, 1, 2, 3, 4, 5, 6

Entry = tuple[int, Any]  # a dispatch table entry: (code, production or turtle function)
Node = tuple[Module, int, int, Any]  # a stack node (module, depth, ilevel, rest: Node | None)
Args = tuple[float, ...]  # a site's prior arguments
# A production's outcome: a successor list, a _Need or None. Any: the hot loop tells them
# apart by `__class__` (faster than isinstance), which mypy does not narrow.
Outcome = Any


class NeedSite(BaseException):
    """Raised by the replay context when a production asks for a value not chosen yet.
    A BaseException so that no `except Exception` in generated code can swallow it."""

    def __init__(self, site: int, args: Args) -> None:
        self.site = site
        self.args = args


class ReplayCtx:
    """The `ctx` a production receives: answers from the values already chosen (each method
    reads the next one itself: a production's random calls are the hottest calls there)."""

    __slots__ = ("values", "sites", "pos")

    def __init__(self) -> None:
        self.values: tuple[float, ...] = ()
        self.sites: tuple[int, ...] = ()
        self.pos = 0

    def _impure(self, site: int, args: Args) -> float:
        """The next value is not one for `site`: ProgramError; past the values: NeedSite."""
        pos = self.pos
        if pos < len(self.values):
            raise ProgramError(
                f"generated code is not pure: replay asked for site {site}, "
                f"recorded site {self.sites[pos]}"
            )
        raise NeedSite(site, args)

    def normal(self, site: int, mu: float, sigma: float) -> float:
        pos = self.pos
        if pos < len(self.values) and self.sites[pos] == site:
            self.pos = pos + 1
            return self.values[pos]
        return self._impure(site, (mu, sigma))

    def uniform(self, site: int, a: float, b: float) -> float:
        pos = self.pos
        if pos < len(self.values) and self.sites[pos] == site:
            self.pos = pos + 1
            return self.values[pos]
        return self._impure(site, (a, b))

    def bernoulli(self, site: int, p: float) -> float:
        pos = self.pos
        if pos < len(self.values) and self.sites[pos] == site:
            self.pos = pos + 1
            return self.values[pos]
        return self._impure(site, (p,))

    def categorical(self, site: int, weights: Args) -> float:
        pos = self.pos
        if pos < len(self.values) and self.sites[pos] == site:
            self.pos = pos + 1
            return self.values[pos]
        return self._impure(site, tuple(weights))

    def choose(self, site: int, probs: Args) -> int:
        pos = self.pos
        if pos < len(self.values) and self.sites[pos] == site:
            self.pos = pos + 1
            return int(self.values[pos])
        return int(self._impure(site, tuple(probs)))


class Particle:
    """One particle's plain state. Shared parts are immutable, so `copy` is shallow."""

    __slots__ = (
        "stack",
        "turtle",
        "tstack",
        "poly",
        "prims",
        "n_prims",
        "trace",
        "values",
        "sites",
        "cont",
        "need",
        "in_interp",
        "last",
        "status",
        "limit",
        "work",
    )

    def __init__(self, stack: Node | None, turtle: Turtle | Turtle3) -> None:
        self.stack = stack
        self.turtle = turtle
        self.tstack: Cons | None = None
        self.poly: Cons | None = None
        self.prims: Cons | None = None  # cons list, newest first
        self.n_prims = 0
        self.trace: Cons | None = None  # cons list of (site, features, value)
        self.values: tuple[float, ...] = ()  # replay values for the module on top of the stack
        self.sites: tuple[int, ...] = ()  # their site indices
        self.cont = False  # some replay value is continuous (then replays are not memoized)
        self.need: tuple[int, Args] | None = None
        self.in_interp = False  # the top module's production returned None
        self.last: Prim | None = None  # primitive drawn by the last step
        self.status = "live"
        self.limit: str | None = None  # the cap's name when status is "limit"
        self.work = 0  # modules expanded or interpreted so far (see MAX_WORK)

    def copy(self) -> Particle:
        q = _new_particle(Particle)
        q.stack = self.stack
        q.turtle = self.turtle
        q.tstack = self.tstack
        q.poly = self.poly
        q.prims = self.prims
        q.n_prims = self.n_prims
        q.trace = self.trace
        q.values = self.values
        q.sites = self.sites
        q.cont = self.cont
        q.need = self.need
        q.in_interp = self.in_interp
        q.last = self.last
        q.status = self.status
        q.limit = self.limit
        q.work = self.work
        return q


_new_particle = object.__new__


class _Need(tuple):  # type: ignore[type-arg]
    """A production's request for a value, `(site, prior args)` (the memoizable form of
    NeedSite): a tuple, so that it becomes the particle's `need` as it is."""

    __slots__ = ()


_MISS = object()
AXIOM = "<axiom>"  # pseudo-module at depth -1 whose production is the axiom
_AXIOM_NODE: Node = ((AXIOM,), -1, 0, None)  # every particle's first stack
MAX_CACHE = 200_000


def _where(program: Program, base: str, kind: str, mod: Module) -> str:
    """'vines.lsys:24: production B(0.75)': the rule's line from the program's `locations`
    table (`base` is the grammar's file name)."""
    key = "axiom" if mod[0] == AXIOM else f"{kind} {mod[0]}"
    at = program.locations.get(key)
    loc = f"{printable(base or program.name)}:{at[0]}: " if at else ""
    if mod[0] == AXIOM:
        return f"{loc}axiom"
    args = ", ".join(f"{v:g}" if isinstance(v, float) else repr(v) for v in mod[1:])
    return f"{loc}{kind} {mod[0]}({args})" if len(mod) > 1 else f"{loc}{kind} {mod[0]}"


class Deriver:
    """Steps particles of one program. Holds the program's dispatch table (module name ->
    what to do with it: its production, interpretation rule or turtle symbol function), one
    replay ctx and memo tables: a production is pure, so its outcome (successor or the next
    request) depends only on the module and the values replayed; outcomes are memoized
    while those values are all discrete."""

    def __init__(
        self, program: Program, max_modules: int = DEFAULT_MAX_MODULES, max_work: int | None = None
    ) -> None:
        self.program = program
        self.base = str(program.source or "").replace("\\", "/").rsplit("/", 1)[-1]
        self.max_work = MAX_WORK if max_work is None else max_work
        self.max_prims = MAX_PRIMITIVES
        self.prods = dict(program.productions)
        self.prods[AXIOM] = program.axiom
        self.interp = dict(program.interpretation)
        self.dlen = program.derivation_length
        self.angle = float(program.angle)
        self.max_modules = max_modules
        if program.dim not in (2, 3):
            raise ProgramError(
                f"program {printable(program.name)}: dim must be 2 or 3, got {program.dim!r}"
            )
        # the turtle: 2D (turtle.py) or 3D (turtle3d.py), the same calling convention
        self.dim = program.dim
        self.ops = TURTLE3D_OPS if self.dim == 3 else TURTLE_OPS
        self.ctx = ReplayCtx()
        # name -> (code, function): how `advance` treats a module first; `after`: once its
        # production does not apply (interpreted only, too deep, or its conditions all false)
        self.table: dict[Any, Entry] = {}
        self.after: dict[Any, Entry] = {}
        for name in list(self.prods) + list(self.interp) + list(self.ops) + [CUT, HALT]:
            self._entry(name)
        self.pcache: dict[object, Outcome] = {}
        self.icache: dict[object, Outcome] = {}

    def start(self, turtle: Turtle) -> Particle:
        """A new particle at `turtle` = (x, y, heading, width); the axiom's modules get
        depth 0 (the axiom runs as a pseudo-module, so it may draw random values too). A 3D
        program's turtle starts at that pose in the XY plane (`turtle3d.start3d`)."""
        if self.dim == 3:
            x, y, h, w = turtle
            return Particle(_AXIOM_NODE, start3d(x, y, h, w, self.program.tropism))
        return Particle(_AXIOM_NODE, turtle)

    def _call(self, p: Particle, fn: Callable[..., Any], kind: str, mod: Module) -> Outcome:
        """Run `fn` with the particle's replay values: successor list, None or a _Need."""
        ctx = self.ctx
        ctx.values = p.values
        ctx.sites = p.sites
        ctx.pos = 0
        try:
            succ = fn(ctx, *mod[1:])
        except NeedSite as need:
            self._check_prior(need, fn, kind, mod)
            return _Need((need.site, need.args))
        except ProgramError as err:
            raise ProgramError(f"{self._where(fn, kind, mod)}: {err}") from None
        except RecursionError:
            raise ProgramError(f"{self._where(fn, kind, mod)}: runaway recursion") from None
        except Exception as err:
            raise ProgramError(
                f"{self._where(fn, kind, mod)}: {type(err).__name__}: {err}"
            ) from None
        if succ.__class__ is not list:
            if succ is None:
                return None
            if not isinstance(succ, list | tuple):
                raise ProgramError(
                    f"{self._where(fn, kind, mod)}: returned "
                    f"{type(succ).__name__}, not a list of modules"
                )
            succ = list(succ)
        for m in succ:
            if m.__class__ is not tuple or not m or m[0].__class__ is not str:
                raise ProgramError(
                    f"{self._where(fn, kind, mod)}: successor {m!r} is not a module tuple"
                )
        return succ

    def _where(self, fn: Callable[..., Any], kind: str, mod: Module) -> str:
        return _where(self.program, self.base, kind, mod)

    def _check_prior(self, need: NeedSite, fn: Callable[..., Any], kind: str, mod: Module) -> None:
        """ProgramError when a production asks for a value with prior arguments its site's
        distribution does not accept (`prior_problem`): no argument is repaired silently."""
        sites = self.program.sites
        if not (isinstance(need.site, int) and 0 <= need.site < len(sites)):
            raise ProgramError(
                f"{self._where(fn, kind, mod)}: asks for site {need.site!r}, "
                f"not one of the program's {len(sites)} sites"
            )
        site = sites[need.site]
        bad = prior_problem(site.kind, need.args)
        if bad:
            raise ProgramError(
                f"{self._where(fn, kind, mod)}: {site.source or site.id} "
                f"(line {site.line}:{site.col}): {bad}"
            )

    def _memo(
        self,
        p: Particle,
        fn: Callable[..., Any],
        kind: str,
        mod: Module,
        cache: dict[object, Outcome],
        key: object,
    ) -> Outcome:
        res = self._call(p, fn, kind, mod)
        if key is not None:
            if len(cache) >= MAX_CACHE:
                cache.clear()
            cache[key] = res
        return res

    def advance(self, p: Particle) -> int:
        """Run `p` to its next resampling point; returns DRAWN, NEED, DONE or LIMIT (one
        particle of `advance_all`)."""
        return self.advance_all((p,))[0]

    def advance_all(self, parts: Iterable[Particle]) -> list[int]:
        """Run each particle, in turn, to its next resampling point; returns its outcome,
        DRAWN, NEED, DONE or LIMIT, in a list.

        After drawing, a particle looks ahead: it goes on with its deterministic work up
        to its next request (then `p.need` is set), its next drawing symbol or its end (then
        `p.stack` is None), and still returns DRAWN; done before resampling, this work is
        shared by the copies. SMC advances the particles of a round in one call: the
        program's tables are read once, not once per particle.

        Long because it is the derivation's hot loop: one look-up in the dispatch table per
        module, productions, interpretation rules and memoization inlined; every turtle
        symbol goes through its function of the program's one turtle semantics
        (`turtle.TURTLE_OPS` in 2D, `turtle3d.TURTLE3D_OPS` in 3D)."""
        table, after, pcache = self.table, self.after, self.pcache
        dlen, angle, max_prims = self.dlen, self.angle, self.max_prims
        max_work, max_modules = self.max_work, self.max_modules
        out: list[int] = []
        for p in parts:
            stack = p.stack
            turtle, tstack, poly = p.turtle, p.tstack, p.poly
            ops = 0
            max_ops = max_work - p.work
            if max_ops > max_modules:
                max_ops = max_modules
            # the successor being read: seq[i:] at depth sdepth, level slevel, then `stack`
            seq: list[Module] | tuple[()] = ()
            i = n = sdepth = slevel = 0
            node: Node | None = None  # the stack node `mod` came from; None: from seq
            mod: Module = ()
            res: Outcome
            drew = False
            stop = 0  # the outcome, once the particle stops before its stack runs out
            try:
                while True:
                    if i < n:
                        mod = seq[i]
                        i += 1
                        depth, ilevel, node = sdepth, slevel, None
                    elif stack is not None:
                        node = stack
                        mod, depth, ilevel, stack = node
                    else:
                        break
                    ops += 1
                    if ops > max_ops:
                        if p.work + ops > max_work:
                            raise self._runaway(
                                f"expanded or interpreted more than {max_work} modules"
                            )
                        p.stack = node or _spill(seq, i - 1, sdepth, slevel, stack)
                        stop = DRAWN if drew else LIMIT
                        break
                    try:
                        code, fn = table[mod[0]]
                    except KeyError:
                        code, fn = self._entry(mod[0])
                    if code == _PROD:
                        if ilevel == 0 and depth < dlen and not p.in_interp:
                            # memoized outcome while the replay values are all discrete
                            values = p.values
                            if p.cont:
                                res = self._call(p, fn, "production", mod)
                            else:
                                key = (mod, values) if values else mod
                                try:
                                    res = pcache[key]
                                except KeyError:
                                    res = self._memo(p, fn, "production", mod, pcache, key)
                            if res.__class__ is _Need:
                                p.stack = node or _spill(seq, i - 1, sdepth, slevel, stack)
                                p.need = res
                                stop = DRAWN if drew else NEED
                                break
                            if values:
                                p.values, p.sites, p.cont = (), (), False
                            if res is not None:  # read the successor next
                                if i < n:
                                    stack = _spill(seq, i, sdepth, slevel, stack)
                                seq, i, n, sdepth, slevel = res, 0, len(res), depth + 1, 0
                                continue
                        code, fn = after[mod[0]]
                    if code == _INTERP:
                        res = self._interpret(p, fn, mod, ilevel)
                        if res.__class__ is _Need:
                            p.stack = node or _spill(seq, i - 1, sdepth, slevel, stack)
                            p.need = res
                            stop = DRAWN if drew else NEED
                            break
                        if res is not None:
                            if i < n:
                                stack = _spill(seq, i, sdepth, slevel, stack)
                            seq, i, n, sdepth, slevel = res, 0, len(res), depth, ilevel + 1
                            continue
                        code, fn = self._turtle_entry(mod[0])
                    if code >= _TURTLE:
                        if drew and code == _DRAW:
                            p.stack = node or _spill(seq, i - 1, sdepth, slevel, stack)
                            stop = DRAWN
                            break
                        turtle, tstack, poly, prim = fn(mod, turtle, tstack, poly, angle)
                        if prim is None:
                            continue
                        p.last = prim
                        p.prims = (prim, p.prims)
                        p.n_prims += 1
                        if p.n_prims > max_prims:
                            raise self._runaway(f"drew more than {max_prims} primitives")
                        drew = True
                    elif code == _CUT:
                        stack = _cut(_spill(seq, i, sdepth, slevel, stack))
                        seq, i, n = (), 0, 0
                    elif code == _HALT:
                        stack, seq, i, n = None, (), 0, 0
            except (TypeError, ValueError, IndexError) as err:  # malformed turtle arguments
                raise ProgramError(f"turtle: bad module {mod!r}: {err}") from None
            finally:
                p.work += ops
            if stop:
                p.turtle, p.tstack, p.poly = turtle, tstack, poly
                out.append(stop)
            else:  # the stack ran out
                p.stack, p.turtle, p.tstack, p.poly = None, turtle, tstack, poly
                out.append(DRAWN if drew else DONE)
        return out

    def _interpret(self, p: Particle, fn: Callable[..., Any], mod: Module, ilevel: int) -> Outcome:
        """The outcome of `mod`'s interpretation rule (memoized as productions are)."""
        if ilevel >= MAX_INTERP_DEPTH:
            raise ProgramError(
                f"interpretation rules recurse deeper than {MAX_INTERP_DEPTH} "
                f"levels (at module {mod[0]})"
            )
        if p.cont:
            res = self._call(p, fn, "interpretation", mod)
        else:
            key = (mod, p.values) if p.values else mod
            res = self.icache.get(key, _MISS)
            if res is _MISS:
                res = self._memo(p, fn, "interpretation", mod, self.icache, key)
        if res.__class__ is _Need:
            p.in_interp = True
            return res
        p.in_interp = False
        if p.values:
            p.values, p.sites, p.cont = (), (), False
        return res

    def _runaway(self, what: str) -> ProgramError:
        name = printable(self.base or self.program.name)
        return ProgramError(
            f"{name}: one sample {what}, the most any sample may do: the "
            "grammar's work has no end in sight (lower its 'derivation "
            "length:' or 'max primitives:')"
        )

    def _entry(self, name: Any) -> Entry:
        """How `advance` treats a module name (then kept in `table`), and what it does once
        the name's production does not apply (kept in `after`)."""
        after = (_INTERP, self.interp[name]) if name in self.interp else self._turtle_entry(name)
        self.after[name] = after
        entry = (_PROD, self.prods[name]) if name in self.prods else after
        self.table[name] = entry
        return entry

    def _turtle_entry(self, name: Any) -> Entry:
        op = self.ops.get(name)
        if op is not None:
            return (_DRAW if name in DRAWING else _TURTLE, op)
        return ({CUT: _CUT, HALT: _HALT}.get(name, _IGNORE), None)


def _spill(
    seq: list[Module] | tuple[()], i: int, depth: int, ilevel: int, stack: Node | None
) -> Node | None:
    """The stack with the modules `seq[i:]` (at `depth` and `ilevel`) pushed on top."""
    for k in range(len(seq) - 1, i - 1, -1):
        stack = (seq[k], depth, ilevel, stack)
    return stack


def _cut(stack: Node | None) -> Node | None:
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
