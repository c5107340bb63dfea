"""Sequential (depth-first, leftmost-first) derivation has the same distribution as parallel
rewriting for context-free grammars.

Parallel rewriting is implemented here, from the generated production functions and a ctx
that samples the prior; the drawn primitives of several thousand prior samples are compared
with those of `ngpm_runtime.inference.smc.forward` by a chi-square test of homogeneity."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest
from scipy.stats import chi2_contingency

from ngpm_compiler.language.compile import compile_grammar

smc = pytest.importorskip("ngpm_runtime.inference.smc")

N = 2000  # samples per side
P_MIN = 1e-3

GRAMMARS = {
    "branching": """
angle: 30
derivation length: 3
Axiom: A
A --> F [ + A ] A : 0.3
    | F [ - A ]   : 0.3
    | F           : 0.4
""",
    "parametric": """
derivation length: 4
Axiom: B(2)
B(n) : n > 0 --> F(1 + flip(0.5)) +(30 * categorical(1, 2, 1)) B(n - 1) [ -(45) C ]
C --> F(0.5) : 0.5 | * : 0.5
""",
    "interpreted": """
derivation length: 3
Axiom: A
A --> F L A : 0.5 | @O(0.5) : 0.5
interpretation:
L --> [ +(60 * (2 * flip(0.5) - 1)) ~l(1 + flip(0.3), 0.5) ]
""",
}


class PriorCtx:
    """The prior, answered directly (no replay needed: each call is made once)."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def normal(self, site, mu, sigma):
        return float(self.rng.normal(mu, sigma))

    def uniform(self, site, a, b):
        return float(self.rng.uniform(a, b))

    def bernoulli(self, site, p):
        return float(self.rng.random() < p)

    def categorical(self, site, weights):
        w = np.asarray(weights, float)
        return float(self.rng.choice(len(w), p=w / w.sum()))

    def choose(self, site, probs):
        return int(self.rng.choice(len(probs), p=np.asarray(probs) / np.sum(probs)))


def parallel_derivation(program, ctx) -> list[tuple]:
    """Rewrite every module of the string at once, derivation_length times."""
    string = program.axiom(ctx)
    for _ in range(program.derivation_length):
        new, changed = [], False
        for m in string:
            fn = program.productions.get(m[0])
            succ = fn(ctx, *m[1:]) if fn is not None else None
            if succ is None:
                new.append(m)
            else:
                new.extend(succ)
                changed = True
        string = new
        if not changed:
            break
    return string


def interpret(program, ctx, string: list[tuple], level: int = 0) -> list[tuple]:
    out: list[tuple] = []
    for m in string:
        fn = program.interpretation.get(m[0])
        succ = fn(ctx, *m[1:]) if fn is not None else None
        out.extend([m] if succ is None else interpret(program, ctx, succ, level + 1))
    return out


def turtle(program, string: list[tuple]) -> list[tuple]:
    """A minimal 2D turtle for F f + - [ ] ! ~l @O, primitives as the runtime writes them."""
    x, y, h = program.start
    w, stack, prims = 1.0, [], []
    for m in string:
        name = m[0]
        if name in ("F", "f"):
            x1 = x + m[1] * math.cos(math.radians(h))
            y1 = y + m[1] * math.sin(math.radians(h))
            if name == "F":
                prims.append(("seg", x, y, x1, y1, w))
            x, y = x1, y1
        elif name == "+":
            h += m[1]
        elif name == "-":
            h -= m[1]
        elif name == "[":
            stack.append((x, y, h, w))
        elif name == "]":
            x, y, h, w = stack.pop()
        elif name == "!":
            w = m[1]
        elif name == "~l":
            prims.append(("leaf", x, y, h, m[1], m[2]))
        elif name == "@O":
            prims.append(("disk", x, y, m[1]))
    return prims


def key(prims) -> tuple:
    return tuple((p[0],) + tuple(round(float(v), 6) + 0.0 for v in p[1:]) for p in prims)


def parallel_samples(program, n: int, seed: int) -> Counter:
    rng = np.random.default_rng(seed)
    ctx = PriorCtx(rng)
    return Counter(
        key(turtle(program, interpret(program, ctx, parallel_derivation(program, ctx))))
        for _ in range(n)
    )


def forward_samples(program, n: int) -> Counter:
    return Counter(key(smc.forward(program, seed=s).primitives) for s in range(n))


def homogeneity_p(a: Counter, b: Counter) -> float:
    """Chi-square p-value that two samples come from one distribution (rare outcomes pooled)."""
    rows, other = [], [0, 0]
    for k in set(a) | set(b):
        if a[k] + b[k] >= 10:
            rows.append([a[k], b[k]])
        else:
            other[0] += a[k]
            other[1] += b[k]
    if sum(other) >= 10:
        rows.append(other)
    assert len(rows) >= 3, "too few distinct outcomes for a meaningful test"
    return float(chi2_contingency(np.array(rows)).pvalue)


@pytest.mark.parametrize("name", sorted(GRAMMARS))
def test_sequential_equals_parallel(name: str) -> None:
    program = compile_grammar(GRAMMARS[name], filename=f"{name}.lsys").program()
    seq = forward_samples(program, N)
    par = parallel_samples(program, N, seed=12345)
    assert homogeneity_p(seq, par) > P_MIN


def test_the_comparison_detects_a_different_distribution() -> None:
    """Power check: the same test rejects a grammar whose probabilities differ a little."""
    program = compile_grammar(GRAMMARS["branching"]).program()
    other = compile_grammar(
        GRAMMARS["branching"].replace(
            ": 0.3\n    | F [ - A ]   : 0.3", ": 0.38\n    | F [ - A ]   : 0.22"
        )
    ).program()
    assert homogeneity_p(forward_samples(program, N), parallel_samples(other, N, 7)) < P_MIN
