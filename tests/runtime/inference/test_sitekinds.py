"""The site-kind table (inference/sitekinds.py): it covers every kind the compiler emits, and
each kind's parts fit together: argument counts, network output widths and heads, prior and
proposal densities, tempering and the networks' training targets."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from ngpm_runtime.inference import distributions as dist
from ngpm_runtime.inference.sitekinds import KINDS, MIXTURE, SIGMOID, SITE_KINDS, SOFTMAX
from ngpm_runtime.program import SITE_KINDS as PROGRAM_KINDS
from ngpm_runtime.program import Site, prior_problem
from repo_paths import REPO

# a grammar with every random call of the language and a stochastic production group
EVERY_CALL = """
viewport: -5 5 -5 5
derivation length: 2

Axiom: A

production:

A --> +(gauss(0, 10)) +(normal(1, 2)) F(uniform(1, 2)) !(flip(0.3)) !(bernoulli(0.6)) B
B --> f(categorical(1, 2, 3)) f(choice(2, 1)) : 0.25
    | F : 0.75

endlsystem
"""

ARGS = {
    "normal": [1.0, 2.0],
    "uniform": [-1.0, 3.0],
    "bernoulli": [0.3],
    "categorical": [1.0, 2.0, 3.0],
}


def _site(kind: str) -> Site:
    return Site(index=0, id=f"x/{kind}", kind=kind, k=3)


def _params(kind: str, n: int, K: int, rng: np.random.Generator) -> np.ndarray:
    """Random valid guide outputs of a site of `kind` (k = 3 categories)."""
    table = KINDS[kind]
    p = rng.normal(size=(n, table.n_out(K, 3)))
    if table.head == MIXTURE:
        p[:, :K] -= np.logaddexp.reduce(p[:, :K], axis=1, keepdims=True)
    elif table.head == SIGMOID:
        p = 1 / (1 + np.exp(-p))
    else:
        p = np.exp(p) / np.exp(p).sum(axis=1, keepdims=True)
    return p


def test_the_table_covers_every_kind_the_compiler_emits() -> None:
    from ngpm_compiler.language.compile import compile_grammar, load_grammar
    from ngpm_compiler.language.tables import RANDOM_CALLS

    assert {kind for kind, _, _ in RANDOM_CALLS.values()} <= set(KINDS)
    program = compile_grammar(EVERY_CALL, filename="every.lsys").program()
    assert {s.kind for s in program.sites} == set(KINDS) == set(SITE_KINDS)
    assert PROGRAM_KINDS == SITE_KINDS
    for path in sorted((REPO / "grammars").glob("*.lsys")):
        for site in load_grammar(Path(path)).sites:
            assert site.kind in KINDS, (path.name, site.id)
            assert site.n_args() == KINDS[site.kind].n_args(site.k)


@pytest.mark.parametrize("kind", SITE_KINDS)
def test_each_kind_fits_together(kind: str) -> None:
    table, site, rng = KINDS[kind], _site(kind), np.random.default_rng(3)
    assert table.name == kind and table.head in (MIXTURE, SIGMOID, SOFTMAX)
    assert table.continuous == (table.head == MIXTURE)
    assert site.n_args() == len(ARGS[kind]) and table.weighted == (kind == "categorical")
    assert prior_problem(kind, tuple(ARGS[kind])) == ""
    K, n = 3, 400
    assert table.n_out(K, 3) == sum(w for _, w in table.columns(K, 3))
    args = np.tile(ARGS[kind], (n, 1))
    values, log_p = dist.prior_draw(site, args, rng)
    np.testing.assert_allclose(log_p, dist.prior_logpdf(site, args, values), rtol=1e-12)
    params = _params(kind, n, K, rng)
    assert table.output_problem(params[:5], K, 1e-3) == ""
    values, log_q = dist.proposal_draw(site, args, params, rng)
    np.testing.assert_allclose(
        log_q, dist.proposal_logpdf(site, args, params, values), rtol=1e-12, atol=1e-12
    )
    assert np.isfinite(log_q).all()
    np.testing.assert_array_equal(table.temper(params, 1.0, 1.0), params)
    tempered = table.temper(params, 2.0, 2.0)  # another proposal of the same layout
    assert tempered.shape == params.shape and not np.allclose(tempered, params)
    values, log_q = dist.proposal_draw(site, args, tempered, rng)
    np.testing.assert_allclose(
        log_q, dist.proposal_logpdf(site, args, tempered, values), rtol=1e-12, atol=1e-12
    )


@pytest.mark.parametrize("kind", [k for k in SITE_KINDS if KINDS[k].continuous])
def test_training_targets_invert_the_proposal_map(kind: str) -> None:
    """to_z maps a value to the z of the proposal's mixture: a one-component mixture at z
    with a tiny sd proposes the value back."""
    table, site, rng = KINDS[kind], _site(kind), np.random.default_rng(5)
    args = np.tile(ARGS[kind], (50, 1))
    values = dist.prior_sample(site, args, rng)
    z, log_jac = table.to_z(values, args, 1e-7)
    params = np.stack([np.zeros(50), z, np.full(50, -30.0)], axis=1)
    if kind == "normal":  # the mixture is in prior units: mean = mu + sigma * m
        np.testing.assert_allclose(log_jac, -np.log(args[:, 1]))
    back = table.proposal_sample(args, params, rng)
    np.testing.assert_allclose(back, values, rtol=1e-9, atol=1e-9)


def test_the_table_answers_for_the_api() -> None:
    """distributions.py and program.py read the table: an unknown kind is one error."""
    from ngpm_runtime.errors import ProgramError

    odd = Site(index=0, id="odd", kind="poisson")
    with pytest.raises(ProgramError, match="unknown kind 'poisson'"):
        dist.prior_sample(odd, np.zeros((2, 1)), np.random.default_rng(0))
    with pytest.raises(ValueError, match="unknown site kind"):
        dist.temper("poisson", np.zeros((2, 1)), 2.0, 2.0)
    assert prior_problem("bernoulli", (1.5,)) == KINDS["bernoulli"].args_problem([1.5], False)


def test_no_module_switches_on_kind_names() -> None:
    """The runtime and the compiler ask KINDS what a kind is (`.weighted`, `.head`, ...)
    instead of comparing kind names; only the table itself names the kinds' parts."""
    names = "|".join(SITE_KINDS)
    switch = re.compile(rf"""kind\)?\s*(==|!=|\bin\b)\s*[(\[{{]?\s*["']({names})["']""")
    found = []
    for root in (REPO / "ngpm_compiler", REPO / "runtime" / "ngpm_runtime"):
        for path in sorted(root.rglob("*.py")):
            if path.name == "sitekinds.py":
                continue
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if switch.search(line):
                    found.append(f"{path.relative_to(REPO)}:{n}: {line.strip()}")
    assert not found, "\n".join(found)
    assert switch.search('if s.kind == "categorical":')  # the pattern finds a switch
