"""Code generation: golden files, the generated module's protocol, ruff-clean output."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from ngpm_runtime.program import Program, load_program
from repo_paths import DATA, REPO

from ngpm_compiler.language.compile import compile_grammar, write_compiled
from ngpm_compiler.language.errors import GrammarError

GOLDEN = Path(__file__).parent / "golden"
GRAMMARS = sorted(p.stem for p in (REPO / "grammars").glob("*.lsys"))


class FixedCtx:
    """Answers every ctx call with a fixed value and records the calls."""

    def __init__(self, value: float = 0.0, choice: int = 0) -> None:
        self.value, self.choice, self.calls = value, choice, []

    def normal(self, site, mu, sigma):
        self.calls.append(("normal", site, mu, sigma))
        return mu + self.value * sigma

    def uniform(self, site, a, b):
        self.calls.append(("uniform", site, a, b))
        return a + self.value * (b - a)

    def bernoulli(self, site, p):
        self.calls.append(("bernoulli", site, p))
        return 1.0

    def categorical(self, site, weights):
        self.calls.append(("categorical", site, weights))
        return 0.0

    def choose(self, site, probs):
        self.calls.append(("choose", site, probs))
        return self.choice


def compiled(name: str):
    return compile_grammar(REPO / "grammars" / f"{name}.lsys", filename=f"grammars/{name}.lsys")


@pytest.mark.parametrize("name", GRAMMARS)
def test_golden(name: str) -> None:
    """golden/<name>_sampler.py equals fresh output (UPDATE_GOLDEN=1 rewrites it); a grammar
    whose sampler the runtime ships (vines, vines3d) has that file as its golden file."""
    code = compiled(name).source_code
    shipped = DATA / f"{name}_sampler.py"
    path = shipped if shipped.is_file() else GOLDEN / f"{name}_sampler.py"
    if os.environ.get("UPDATE_GOLDEN") == "1":
        path.write_text(code)
    assert path.is_file(), f"missing golden file {path}; run with UPDATE_GOLDEN=1"
    assert code == path.read_text(), f"{name}: generated code differs from {path}"


@pytest.mark.parametrize("name", GRAMMARS)
def test_program_is_consistent(name: str) -> None:
    c = compiled(name)
    prog = c.program()
    assert isinstance(prog, Program)
    assert prog.name == name and prog.grammar_hash == c.grammar_hash
    assert c.grammar_hash.startswith("sha256:") and len(c.grammar_hash) == 7 + 64
    assert [s.index for s in prog.sites] == list(range(len(prog.sites)))
    assert len({s.id for s in prog.sites}) == len(prog.sites)
    assert prog.sites == c.sites
    js = c.sites_json()
    assert js["grammar"] == name and len(js["sites"]) == len(c.sites)


def test_write_compiled_and_load(tmp_path: Path) -> None:
    c = compiled("vines")
    sampler, sites = write_compiled(c, tmp_path)
    assert sampler.name == "vines_sampler.py" and sites.name == "vines_sites.json"
    prog = load_program(sampler)
    assert prog.derivation_length == 400 and prog.viewport == (-12.0, 12.0, -22.0, 2.0)
    assert set(prog.productions) == {"S", "B", "L", "Lf", "P", "T", "K", "C1", "C2"}
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_vines_productions_follow_protocol() -> None:
    prog = compiled("vines").program()
    ctx = FixedCtx(value=1.0)
    succ = prog.productions["B"](ctx, 0.75)
    assert succ == [("+", 22.5), ("!", 0.75), ("F", 2.0), ("L",), ("P",), ("T", 0.75)]
    b = prog.site("B/0/normal0").index
    assert ctx.calls == [("normal", b, 0.0, 22.5)]
    # conditions: K rewrites while w > WMIN, else no rule applies (None)
    assert prog.productions["K"](FixedCtx(), 0.5) == [("C1", 0.5), ("C2", 0.5)]
    assert prog.productions["K"](FixedCtx(), 0.1) is None
    # a stochastic group: alternative 1 of C1 deletes the module
    ctx = FixedCtx(choice=1)
    assert prog.productions["C1"](ctx, 0.5) == []
    assert ctx.calls == [("choose", prog.site("C1/choice").index, (0.66, 0.34))]
    ctx = FixedCtx(choice=0)
    assert prog.productions["C1"](ctx, 0.5) == [("[",), ("B", 0.5 * 0.975), ("]",)]
    # leaf: default arguments filled, nested expression of a parameter
    ctx = FixedCtx(value=0.0)
    succ = prog.productions["Lf"](ctx, -1.0)
    assert succ[1] == ("f", -1.0) and succ[2] == ("+", -45.0)
    assert prog.axiom(FixedCtx()) == [("S",)]


def test_defaults_and_types() -> None:
    src = "angle: 30\nAxiom: F f + - ~l ~l(2) @O !(2) | [ ] { . } % halt A(1 > 0)\n"
    prog = compile_grammar(src).program()
    succ = prog.axiom(FixedCtx())
    assert succ == [
        ("F", 1.0),
        ("f", 1.0),
        ("+", 30.0),
        ("-", 30.0),
        ("~l", 1.0, 1.0),
        ("~l", 2.0, 1.0),
        ("@O", 1.0),
        ("!", 2.0),
        ("|",),
        ("[",),
        ("]",),
        ("{",),
        (".",),
        ("}",),
        ("%",),
        ("halt",),
        ("A", 1.0),
    ]
    assert all(type(a) is float for m in succ for a in m[1:])


def test_math_in_degrees_and_random_calls() -> None:
    src = (
        "#define K 2\nAxiom: A(3)\nA(x) --> F(sin(30) + cos(60) + atan2(1, 1) + x ^ K) "
        "F(min(x, 1, 2) + max(x, 5) + abs(-x) + sqrt(16) + floor(2.5) + ceil(2.5) "
        "+ round(2.5) + pi - pi + 7 % 4) F(flip(0.3) + uniform(1, 3) + gauss(x, 1) "
        "+ categorical(1, 2, 3) + choice(0.5, 0.5) + normal(0, 1) + bernoulli(0.5))\n"
    )
    c = compile_grammar(src)
    prog = c.program()
    ctx = FixedCtx(value=0.5)
    succ = prog.productions["A"](ctx, 3.0)
    assert succ[0][1] == pytest.approx(0.5 + 0.5 + 45.0 + 9.0)
    assert succ[1][1] == pytest.approx(1 + 5 + 3 + 4 + 2 + 3 + 3 + 3)
    assert succ[2][1] == pytest.approx(1.0 + 2.0 + 3.5 + 0.0 + 0.0 + 0.5 + 1.0)
    kinds = [call[0] for call in ctx.calls]
    assert kinds == [
        "bernoulli",
        "uniform",
        "normal",
        "categorical",
        "categorical",
        "normal",
        "bernoulli",
    ]
    ids = [s.id for s in c.sites]
    assert ids == [
        "A/0/bernoulli0",
        "A/0/uniform0",
        "A/0/normal0",
        "A/0/categorical0",
        "A/0/categorical1",
        "A/0/normal1",
        "A/0/bernoulli1",
    ]
    assert [c.sites[call[1]].kind for call in ctx.calls] == [
        "bernoulli",
        "uniform",
        "normal",
        "categorical",
        "categorical",
        "normal",
        "bernoulli",
    ]
    assert c.sites[3].k == 3 and c.sites[4].k == 2


def test_nested_random_calls_and_replay_purity() -> None:
    c = compile_grammar("Axiom: A\nA --> F(gauss(uniform(0, 1), 2))\n")
    prog = c.program()
    ctx = FixedCtx(value=0.25)
    first = prog.productions["A"](ctx)
    again = prog.productions["A"](FixedCtx(value=0.25))
    assert first == again  # a pure function of the values ctx returns
    assert [call[0] for call in ctx.calls] == ["uniform", "normal"]
    assert ctx.calls[1][2] == 0.25  # the uniform's value is the normal's mean


def test_param_names_per_alternative_and_shadowing() -> None:
    src = (
        "#define x 5\nderivation length: 2\nAxiom: A(1) B(2)\n"
        "A(y) : y > 0 --> F(y + x)\nA(z) : z > 0 --> G(z) : 1\nB(x) --> F(x)\n"
    )
    # the second rule has the same condition (parameters renamed): same group
    with pytest.raises(Exception, match="sum to 2"):
        compile_grammar(src.replace("F(y + x)", "F(y + x) : 1"))
    src2 = (
        "#define x 5\nAxiom: A(1) B(2)\nA(y) : y > 0 --> F(y + x)\nA(z) --> G(z)\nB(x) --> F(x)\n"
    )
    prog = compile_grammar(src2).program()
    assert prog.productions["A"](FixedCtx(), 1.0) == [("F", 6.0)]
    assert prog.productions["A"](FixedCtx(), -1.0) == [("G", -1.0)]
    assert prog.productions["B"](FixedCtx(), 2.0) == [("F", 2.0)]  # parameter shadows x


def test_python_keyword_names_are_mangled() -> None:
    src = "#define lambda 2\nAxiom: A(lambda)\nA(ctx, math) --> F(ctx + math + lambda)\n"
    src = src.replace("A(lambda)", "A(lambda, 1)")
    prog = compile_grammar(src).program()
    assert prog.productions["A"](FixedCtx(), 1.0, 2.0) == [("F", 5.0)]


def test_interpretation_rules() -> None:
    c = compiled("bush")
    prog = c.program()
    # bush says 'turtle arguments: lazy': its fork and bend angles are rules of their own
    assert set(prog.interpretation) == {"L", "_late1", "_late2", "_late3"}
    ctx = FixedCtx(value=0.5)
    assert prog.interpretation["L"](ctx) == [("[",), ("+", 0.0), ("~l", 1.2, 0.5), ("]",)]
    assert c.sites[ctx.calls[0][1]].id == "interp:L/0/uniform0"


@pytest.mark.skipif(shutil.which("ruff") is None, reason="ruff not installed")
def test_generated_code_is_ruff_clean(tmp_path: Path) -> None:
    for name in GRAMMARS:
        write_compiled(compiled(name), tmp_path)
    cfg = REPO / "pyproject.toml"
    res = subprocess.run(
        ["ruff", "check", "--config", str(cfg), "--no-cache", str(tmp_path)],
        capture_output=True,
        text=True,
    )
    assert res.returncode == 0, res.stdout + res.stderr


def test_mangled_parameter_names_stay_distinct() -> None:
    prog = compile_grammar("Axiom: A(1, 2)\nA(l, p_l) --> F(l + 10 * p_l)\n").program()
    assert prog.productions["A"](FixedCtx(), 1.0, 2.0) == [("F", 21.0)]


def test_rewritten_turtle_symbol_gets_its_full_arity() -> None:
    prog = compile_grammar("derivation length: 1\nAxiom: F\nF --> F F(2)\n").program()
    assert prog.axiom(FixedCtx()) == [("F", 1.0)]
    assert prog.productions["F"](FixedCtx(), 1.0) == [("F", 1.0), ("F", 2.0)]


def test_logical_values_are_one_or_zero() -> None:
    src = (
        "#define X 2 or 3\n#define Y (1 < 2) + (3 and 4)\nAxiom: A(5)\n"
        "A(v) --> F(v or 0) F(not v) F((v > 1) + (v and 2)) F(0 or 0) F(X) F(Y)\n"
    )
    prog = compile_grammar(src).program()
    assert prog.productions["A"](FixedCtx(), 5.0) == [
        ("F", 1.0),
        ("F", 0.0),
        ("F", 2.0),
        ("F", 0.0),
        ("F", 1.0),
        ("F", 2.0),
    ]


# ---- issue #27: no code from a name or a text, no name the generated code uses -------------

# Each payload sets a global if it ever runs; quotes, newlines and separators try to end a
# string, docstring or comment of the generated module around it.
PAYLOADS = ['__import__("builtins").ngpm_pwned = 1', "__import__('builtins').ngpm_pwned = 1"]
BREAKERS = [
    '"""',
    "'''",
    '"',
    "'",
    "\\",
    "\n",
    "\r",
    "\r\n",
    "\x00",
    "\u2028",
    "\u2029",
    "\x0b",
    "\x0c",
    "\x1c",
    "\x1d",
    "\x1e",
    "\x85",
    "#",
    ";",
    ")",
    "]",
    "__",
    "é",
]
HOSTILE = st.lists(
    st.sampled_from(BREAKERS + PAYLOADS + [";" + p + ";" for p in PAYLOADS]) | st.text(max_size=3),
    min_size=1,
    max_size=8,
).map("".join)


def hostile_grammar(text: str) -> str:
    """A grammar whose rule texts carry `text` in comments (a rule's text, comments between its
    alternatives included, goes into its docstring)."""
    comment = "".join(c for c in text if c not in "\r\n")
    return (
        f"#define N 2  # {comment}\nderivation length: 2\nAxiom: A(N)\n"
        f"A(x) --> F(x) : 0.5  # {comment}\n#{comment}\n    | G(x) : 0.5  # {comment}\n"
        f"G(y) --> F(gauss(y, 1))\n"
    )


def assert_not_pwned() -> None:
    import builtins

    assert not hasattr(builtins, "ngpm_pwned"), "a payload ran"


@settings(max_examples=150, deadline=None, derandomize=True)
@given(name=HOSTILE, text=HOSTILE)
def test_hostile_file_names_and_texts_run_no_code(name: str, text: str) -> None:
    """Compiling and loading never runs anything from the file name or the grammar's text,
    and the path round-trips through the module docstring, PROGRAM.source and the function
    docstrings (whose `(file:line)` the runtime's messages read)."""
    filename = f"{name}.lsys"
    c = compile_grammar(hostile_grammar(text), filename=filename)
    prog = c.program()
    assert_not_pwned()
    assert ast.get_docstring(ast.parse(c.source_code), clean=False) == (
        f"Generated by ngpmc from {filename} -- do not edit."
    )
    assert prog.source == filename
    base = filename.replace("\\", "/").rsplit("/", 1)[-1]
    assert prog.productions["A"].__doc__.rstrip().endswith(f"({base}:4-6)")
    with tempfile.TemporaryDirectory() as out:
        sampler, _ = write_compiled(c, out)
        assert load_program(sampler).source == filename
    assert_not_pwned()


def test_hostile_name_on_disk_runs_nothing(tmp_path: Path) -> None:
    """The red team's file name (finding 1) runs nothing on check, compile, sample or load."""
    name = 'x""";open("PWNED", "w");"""\n#y\u2028.lsys'
    (tmp_path / name).write_text((REPO / "grammars" / "chain.lsys").read_text())
    ngpmc = [sys.executable, "-m", "ngpm_compiler.cli"]
    for args in (
        ["check", name],
        ["compile", name, "-o", "out"],
        ["sample", name, "-o", "s.png", "--size", "32"],
    ):
        proc = subprocess.run(
            [*ngpmc, *args], cwd=tmp_path, capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 0, proc.stderr
    sampler = next((tmp_path / "out").glob("*_sampler.py"))
    assert load_program(sampler).source == name
    assert not (tmp_path / "PWNED").exists()


def test_a_grammar_error_names_a_hostile_file_on_one_line() -> None:
    with pytest.raises(GrammarError) as info:
        compile_grammar("Axiom: A(\n", filename="a\nb\u2028.lsys")
    head = str(info.value).splitlines()[0]
    assert head.startswith("a\\nb\\u2028.lsys:1:")


def test_constants_do_not_shadow_generated_parameters() -> None:
    """Finding 5: `#define arg0 5` with `F --> F(arg0)` drew F(1) (the parameter arg0)."""
    prog = compile_grammar(
        "#define arg0 5\nderivation length: 1\nAxiom: F\nF --> F(arg0)\n"
    ).program()
    assert prog.productions["F"](FixedCtx(), 1.0) == [("F", 5.0)]


# Builtins the generated code uses, others, and the generated module's own names.
TAKEN_NAMES = [
    "bool",
    "int",
    "float",
    "min",
    "max",
    "abs",
    "len",
    "range",
    "round",
    "sum",
    "print",
    "str",
    "list",
    "tuple",
    "type",
    "object",
    "exec",
    "eval",
    "open",
    "__import__",
    "__name__",
    "__builtins__",
    "_",
    "math",
    "ctx",
    "alt",
    "axiom",
    "SITES",
    "PROGRAM",
    "Program",
    "Site",
    "arg0",
    "arg1",
    "produce_A",
    "interpret_B",
    "c_x",
    "p_x",
    "None",
    "True",
    "lambda",
    "l",
    "O",
    "I",
]


@pytest.mark.parametrize("n", TAKEN_NAMES)
def test_builtin_and_generated_names_as_constants_and_parameters(n: str) -> None:
    """Finding 7: a constant or parameter named like a builtin the generated code uses
    (`bool`, ...) crashed; now every name means what the grammar says."""
    src = (
        f"#define {n} 2\n#define K ({n} and 3) + (1 or 0) + round(0.5) + min({n}, 9)\n"
        "derivation length: 1\nAxiom: A(3)\n"
        f"A(v) : v > {n} and not (v < 0) --> F(v + {n} + (v > 1) + (v and 0)) "
        f"B(min(v, {n}), {n} * K)\n"
        f"B({n}, w) --> F({n} + w + (w or 1) + round(0.5) + abs(-1)) A(max({n}, 1))\n"
    )
    prog = compile_grammar(src).program()
    assert prog.productions["A"](FixedCtx(), 3.0) == [("F", 6.0), ("B", 2.0, 10.0)]
    assert prog.productions["B"](FixedCtx(), 5.0, 4.0) == [("F", 12.0), ("A", 5.0)]
    assert prog.productions["A"](FixedCtx(), 1.0) is None


def test_architecture_doc_shows_the_real_generated_module(monkeypatch) -> None:
    """Issue #21: docs/architecture.md section 2 showed a hand-written module (with a
    `Site(dist=...)` field that does not exist). Its example is an excerpt of a fresh compile
    of the grammar it names: every run of lines between `...` lines appears, in order."""
    doc = (REPO / "docs" / "architecture.md").read_text(encoding="utf-8")
    section = doc[doc.index("## 2. The generated module") :]
    block = section[section.index("```python\n") + 10 : section.index("\n```\n")]
    assert "grammars/vines.lsys" in block.splitlines()[0]
    monkeypatch.chdir(REPO)
    code = compile_grammar("grammars/vines.lsys").source_code
    at = 0
    for chunk in block.split("\n...\n"):
        found = code.find(chunk.strip("\n"), at)
        assert found >= 0, f"docs/architecture.md's example is stale here:\n{chunk}"
        at = found + len(chunk.strip("\n"))


def test_3d_module_says_so_and_2d_modules_do_not(tmp_path: Path) -> None:
    """A 3D grammar's module has `DIM = 3` and passes dim, box and tropism to Program; a 2D
    module is as it was before 3D (no DIM, no new fields: the golden files hold it)."""
    for name in GRAMMARS:
        code = compiled(name).source_code
        is_3d = name.endswith("3d")
        assert ("\nDIM = 3  #" in code) == is_3d and ("    dim=DIM,\n" in code) == is_3d
        assert ("box=" in code) == is_3d
    sampler, _ = write_compiled(compiled("tree3d"), tmp_path)
    prog = load_program(sampler)
    assert (prog.dim, prog.box, prog.tropism) == (
        3,
        (-600.0, 600.0, -20.0, 1150.0, -600.0, 600.0),
        (0.0, -1.0, 0.0, 0.22),
    )
    assert prog.viewport == (-600.0, 600.0, -20.0, 1150.0)
    assert compiled("vines").program().dim == 2
    flat = compile_grammar("dimensions: 3\nAxiom: F\n").program()
    assert (flat.dim, flat.box, flat.tropism) == (3, None, None)
