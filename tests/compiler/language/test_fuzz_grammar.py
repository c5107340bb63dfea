"""Fuzz: mutated shipped grammars either compile (to a loadable program that runs a few
steps) or raise GrammarError -- never any other exception."""

from __future__ import annotations

import re

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.inference.smc import smc
from repo_paths import REPO

from ngpm_compiler.language.compile import compile_grammar
from ngpm_compiler.language.errors import GrammarError

SOURCES = [p.read_text() for p in sorted((REPO / "grammars").glob("*.lsys"))]
TOKEN = re.compile(r"\s+|[A-Za-z_][A-Za-z0-9_]*|\d+\.?\d*|-->|.", re.S)
ALPHABET = "()[]{}+-*/%^|!.,:<>=&$\\~@#\n\t 0123456789xwFfABLSOhalt"
SNIPPETS = ["-->", ":", "|", "(", ")", "gauss(0, 1)", "flip(", "*", "/ 0", "1/3", "\n",
            "#define Z 0\n", "derivation length: 2\n", "Axiom:", "A(x, x)", "x", "F(1, 2)",
            "interpretation:\n", "endlsystem\n", "~c", "@O", "halt", "%", "not", "and",
            "module F\n", "1e999", "..", "{", "}", "K(w) : w > 0 --> K(w)\n", "\\"]
FUZZ = settings(max_examples=900, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def compiles_or_grammar_error(text: str) -> None:
    try:
        compiled = compile_grammar(text, filename="fuzz.lsys")
    except GrammarError as e:
        assert str(e).startswith("fuzz.lsys:")
        return
    program = compiled.program()
    assert len(program.sites) == len(compiled.sites)
    runs_a_few_steps(program)


def runs_a_few_steps(program) -> None:
    """A program that compiled runs: a few SMC steps end normally or with one of ngpm's own
    errors (say, a division by zero in a production), never a crash, and never a turtle
    error that `check` should have found (an unmatched bracket)."""
    try:
        smc(program, None, 2, seed=0, max_steps=4, max_modules=2000)
    except NgpmError as err:
        assert "without a matching" not in str(err), err


@st.composite
def char_mutants(draw) -> str:
    text = draw(st.sampled_from(SOURCES))
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, max(0, len(text) - 1)))
        op = draw(st.sampled_from(["delete", "insert", "swap", "snippet"]))
        if op == "delete":
            text = text[:i] + text[i + 1:]
        elif op == "insert":
            text = text[:i] + draw(st.sampled_from(ALPHABET)) + text[i:]
        elif op == "swap" and i + 1 < len(text):
            text = text[:i] + text[i + 1] + text[i] + text[i + 2:]
        else:
            text = text[:i] + draw(st.sampled_from(SNIPPETS)) + text[i:]
    return text


@st.composite
def token_mutants(draw) -> str:
    tokens = TOKEN.findall(draw(st.sampled_from(SOURCES)))
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, len(tokens) - 1))
        op = draw(st.sampled_from(["delete", "duplicate", "swap", "replace"]))
        if op == "delete":
            del tokens[i]
        elif op == "duplicate":
            tokens.insert(i, tokens[i])
        elif op == "swap":
            j = draw(st.integers(0, len(tokens) - 1))
            tokens[i], tokens[j] = tokens[j], tokens[i]
        else:
            tokens[i] = draw(st.sampled_from(tokens + SNIPPETS))
    return "".join(tokens)


@FUZZ
@given(char_mutants())
def test_character_mutations(text: str) -> None:
    compiles_or_grammar_error(text)


@FUZZ
@given(token_mutants())
def test_token_mutations(text: str) -> None:
    compiles_or_grammar_error(text)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.text(alphabet=ALPHABET, max_size=80))
def test_random_text(text: str) -> None:
    compiles_or_grammar_error(text)
