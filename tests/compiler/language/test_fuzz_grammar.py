"""Fuzz: mutated shipped grammars either compile (to a loadable program that runs a few
steps) or raise GrammarError -- never any other exception, never code run from the text."""

from __future__ import annotations

import os
import random
import re
import time

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ngpm_runtime.errors import NgpmError, printable
from ngpm_runtime.inference.smc import SMCOptions, smc
from ngpm_runtime.program import Program
from repo_paths import REPO

from ngpm_compiler.language.compile import compile_grammar
from ngpm_compiler.language.errors import GrammarError

SOURCES = [p.read_text() for p in sorted((REPO / "grammars").glob("*.lsys"))]
TOKEN = re.compile(r"\s+|[A-Za-z_][A-Za-z0-9_]*|\d+\.?\d*|-->|.", re.S)
ALPHABET = "()[]{}+-*/%^|!.,:<>=&$\\~@#\n\t 0123456789xwFfABLSOhalt"
SNIPPETS = [
    "-->",
    ":",
    "|",
    "(",
    ")",
    "gauss(0, 1)",
    "flip(",
    "*",
    "/ 0",
    "1/3",
    "\n",
    "#define Z 0\n",
    "derivation length: 2\n",
    "Axiom:",
    "A(x, x)",
    "x",
    "F(1, 2)",
    "interpretation:\n",
    "endlsystem\n",
    "~c",
    "@O",
    "halt",
    "%",
    "not",
    "and",
    "module F\n",
    "1e999",
    "..",
    "{",
    "}",
    "K(w) : w > 0 --> K(w)\n",
    "\\",
]
FUZZ = settings(
    max_examples=900,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


def compiles_or_grammar_error(text: str) -> None:
    if "\n" not in text and text.strip() and os.path.exists(text):
        return  # compile_grammar reads a one-line str naming a file or folder (`/`) as a path
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
        smc(program, None, 2, options=SMCOptions(seed=0, max_steps=4, max_modules=2000))
    except NgpmError as err:
        assert "without a matching" not in str(err), err


@st.composite
def char_mutants(draw) -> str:
    text = draw(st.sampled_from(SOURCES))
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, max(0, len(text) - 1)))
        op = draw(st.sampled_from(["delete", "insert", "swap", "snippet"]))
        if op == "delete":
            text = text[:i] + text[i + 1 :]
        elif op == "insert":
            text = text[:i] + draw(st.sampled_from(ALPHABET)) + text[i:]
        elif op == "swap" and i + 1 < len(text):
            text = text[:i] + text[i + 1] + text[i] + text[i + 2 :]
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


# ---- issue #27: a seeded fuzz with a time budget ---------------------------------------------

FUZZ_SECONDS = 20.0  # wall-clock budget: the fuzz stops here, or after FUZZ_MOST grammars
FUZZ_MOST = 3000
PAYLOAD = '__import__("builtins").ngpm_pwned = 1'
# What the red team tried: payloads in comments, names the generated code uses, deep nesting,
# absurd headers, invalid priors.
HOSTILE_NAMES = [
    "bool",
    "int",
    "float",
    "min",
    "arg0",
    "arg1",
    "ctx",
    "alt",
    "math",
    "SITES",
    "PROGRAM",
    "produce_A",
    "__import__",
    "__builtins__",
    "c_x",
    "p_x",
    "lambda",
    "None",
]
HOSTILE_SNIPPETS = HOSTILE_NAMES + [
    f'# """;{PAYLOAD};"""\n',
    f"# ''';{PAYLOAD};'''\n",
    "# \\\n",
    "#\x00\r\u2028\u2029\x85\n",
    "#define bool 2\n",
    "#define arg0 5\n",
    "#define math 1\n",
    "#define bool 2\n#define Z (1 and 2)\n",
    "A(bool, int) --> F(bool and int)\n",
    "sin(" * 120,
    "(" * 300,
    "-" * 150,
    "1+" * 300,
    "cos(x and " * 60,
    "max primitives: 1e18\n",
    "derivation length: 1e9\n",
    "max modules: 1e12\n",
    "gauss(0, -1)",
    "uniform(1, 0)",
    "flip(2)",
    "choice(0, 0)",
    "gauss(0, 0)",
]
FILENAMES = [
    'f"""u\\zz.lsys',
    "f\nuzz\u2028.lsys",
    "f'''uzz\x00.lsys",
    f'x""";{PAYLOAD};"""y.lsys',
    f"x\n{PAYLOAD}\n#.lsys",
    f"x\r{PAYLOAD}\r#.lsys",
]


def mutate(rng: random.Random) -> str:
    """A shipped grammar with 1 to 4 character, token or snippet mutations."""
    text = rng.choice(SOURCES)
    for _ in range(rng.randint(1, 4)):
        i = rng.randint(0, max(0, len(text) - 1))
        op = rng.choice(["delete", "insert", "swap", "snippet", "hostile", "tokens"])
        if op == "delete":
            text = text[:i] + text[i + 1 :]
        elif op == "insert":
            text = text[:i] + rng.choice(ALPHABET) + text[i:]
        elif op == "swap" and i + 1 < len(text):
            text = text[:i] + text[i + 1] + text[i] + text[i + 2 :]
        elif op in ("snippet", "hostile"):
            text = (
                text[:i] + rng.choice(SNIPPETS if op == "snippet" else HOSTILE_SNIPPETS) + text[i:]
            )
        else:
            tokens = TOKEN.findall(text)
            j, k = rng.randrange(len(tokens)), rng.randrange(len(tokens))
            tokens[j] = rng.choice([tokens[k], "", tokens[j] * 2] + HOSTILE_NAMES)
            text = "".join(tokens)
    return text


def test_seeded_fuzz_within_a_time_budget() -> None:
    """Thousands of mutated grammars (the red team ran 12,000): each compiles to a module that
    loads, or raises GrammarError with `file:line:col:`; never another exception, never code
    run from the text or the file name. A hostile file name changes neither: the same text
    compiles under it (its path round-trips) or fails with the same error. Every 25th
    compiled program runs a few SMC steps."""
    rng = random.Random(27)
    start, done, compiled = time.monotonic(), 0, 0
    while done < FUZZ_MOST and time.monotonic() - start < FUZZ_SECONDS:
        text, hostile = mutate(rng), rng.choice(FILENAMES)
        done += 1
        plain = compile_or_error(text, "fuzz.lsys", done)
        named = compile_or_error(text, hostile, done)
        if isinstance(plain, GrammarError):
            assert (
                isinstance(named, GrammarError)
                and named.message == plain.message
                and (named.line, named.col) == (plain.line, plain.col)
            ), (done, named, text)
            continue
        assert not isinstance(named, GrammarError), (done, named, text)
        assert named.source == hostile and named.sites == plain.sites
        compiled += 1
        if compiled % 25 == 0:
            runs_a_few_steps(plain)
    assert done >= 100 and compiled >= 10, (done, compiled)  # a floor for a busy machine


def compile_or_error(text: str, filename: str, done: int) -> Program | GrammarError:
    """The loaded program, or the GrammarError (checked to start with `file:line:col: `);
    any other exception, or a payload that ran, fails the test."""
    import builtins

    try:
        return compile_grammar(text, filename=filename).program()
    except GrammarError as e:
        assert re.match(rf"{re.escape(printable(filename))}:\d+:\d+: \S", str(e)), (
            done,
            str(e),
            text,
        )
        return e
    except Exception as e:
        raise AssertionError(
            f"grammar {done} of seed 27 ({filename!r}): {type(e).__name__}: {e}\n{text}"
        ) from None
    finally:
        assert not hasattr(builtins, "ngpm_pwned"), (done, filename, text)
