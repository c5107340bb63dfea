"""Semantic checks (every error class of the language) and the site table."""

from __future__ import annotations

import pytest
from repo_paths import REPO

from ngpm_compiler.language.compile import compile_grammar
from ngpm_compiler.language.errors import GrammarError

VINES = (REPO / "grammars" / "vines.lsys").read_text()


def err(text: str) -> GrammarError:
    with pytest.raises(GrammarError) as info:
        compile_grammar(text, filename="t.lsys")
    return info.value


ERRORS = [
    # (grammar, message fragment, line, col)
    ("Axiom: A\nA --> F(foo(1))\n", "unknown function 'foo'", 2, 9),
    ("Axiom: A\nA --> F(x)\n", "unknown identifier 'x'", 2, 9),
    ("Axiom: A(1)\nA(x) : y > 1 --> F\n", "unknown identifier 'y'", 2, 8),
    ("#define A B + 1\nAxiom: F\n", "unknown identifier 'B'", 1, 11),
    ("Axiom: A\nA --> B(1) B(1, 2)\n", "module B takes 1 argument", 2, 12),
    ("module B(x)\nAxiom: B\n", "module B takes 1 argument", 2, 8),
    ("Axiom: A\nA(x) --> F\n", "module A takes 0 arguments", 2, 1),
    ("Axiom: F(1, 2)\n", "turtle symbol F takes 0 to 1 arguments, got 2", 1, 8),
    ("Axiom: !\n", "turtle symbol ! takes 1 argument, got 0", 1, 8),
    ("Axiom: [(1)\n", "turtle symbol [ takes 0 arguments, got 1", 1, 8),
    ("Axiom: F(gauss(1))\n", "gauss() takes 2 arguments, got 1", 1, 10),
    ("Axiom: F(flip(1, 2))\n", "flip() takes 1 argument, got 2", 1, 10),
    ("Axiom: F(choice(1))\n", "choice() takes at least 2 arguments", 1, 10),
    ("Axiom: F(atan2(1))\n", "atan2() takes 2 arguments, got 1", 1, 10),
    ("Axiom: A\nA --> F : 0.5\nA --> G : 0.4\n", "sum to 0.9, not 1", 2, 11),
    ("Axiom: A\nA --> F : 0.5\n", "sum to 0.5, not 1", 2, 11),
    ("Axiom: A\nA --> F : 1.5\nA --> G : -0.5\n", "not in [0, 1]", 2, 11),
    ("Axiom: A\nA --> F\nA --> G\n", "each needs a probability", 2, 1),
    ("Axiom: A\nA --> F : 1\nA --> G\n", "each needs a probability", 3, 1),
    ("Axiom: A(1)\nA(x) --> F : x\nA(x) --> G : 1 - x\n", "must be a constant expression", 2, 14),
    ("Axiom: A\nA --> F : flip(0.5)\nA --> G : 0.5\n", "not allowed in the probability", 2, 11),
    ("Axiom: A(1)\nA(x) : gauss(0, 1) > x --> F\n", "not allowed in the condition", 2, 8),
    ("define: X = uniform(0, 1)\nAxiom: F\n", "not allowed in constant X", 1, 13),
    ("angle: gauss(0, 1)\nAxiom: F\n", "not allowed in 'angle:'", 1, 8),
    ("#define X 1 / (2 - 2)\nAxiom: F\n", "division by zero in constant X", 1, 13),
    ("#define X 7 % 0\nAxiom: F\n", "division by zero in constant X", 1, 13),
    ("#define X sqrt(-1)\nAxiom: F\n", "cannot evaluate constant X", 1, 11),
    ("#define X 1\n#define X 2\nAxiom: F\n", "defined twice", 2, 9),
    (
        "Axiom: A\nA --> F B\nB --> A\n",
        "recursive rules (A -> B -> A) need a 'derivation length:'",
        2,
        1,
    ),
    ("Axiom: F\nF --> F F\n", "recursive rules (F -> F)", 2, 1),
    ("Axiom: A(1, 2)\nA(x, x) --> F\n", "duplicate parameter 'x' in A", 2, 6),
    ("module A(x, x)\nAxiom: F\n", "duplicate parameter", 1, 8),
    ("Axiom: ~c\n", "unsupported symbol '~c'", 1, 8),
    ("Axiom: @Gs\n", "unsupported symbol '@G'", 1, 8),
    ("A --> F\n", "no 'Axiom:' line", 1, 1),
    ("Axiom: A(1)\nA(x) --> F\nA(x) : x > 1 --> G\n", "never applies", 3, 1),
    ("Axiom: halt\nhalt --> F\n", "turtle symbol halt cannot be rewritten", 2, 1),
    ("module F\nAxiom: A\n", "F is a turtle symbol", 1, 8),
    ("derivation length: 2.5\nAxiom: A\n", "must be an integer >= 0", 1, 20),
    ("max primitives: 0\nAxiom: A\n", "must be an integer >= 1", 1, 17),
    ("viewport: 1 0 0 1\nAxiom: A\n", "xmin < xmax", 1, 1),
    ("Axiom: F(gauss(0, 0))\n", "standard deviation must be > 0", 1, 10),
    ("Axiom: F(uniform(2, 1))\n", "needs a < b", 1, 10),
    ("Axiom: F(flip(2))\n", "probability must be in [0, 1]", 1, 10),
    ("Axiom: F(categorical(0, 0))\n", "weights must be >= 0", 1, 10),
    ("#define pi 3\nAxiom: F\n", "built-in constant", 1, 9),
]


@pytest.mark.parametrize("text,fragment,line,col", ERRORS)
def test_error_classes(text: str, fragment: str, line: int, col: int) -> None:
    e = err(text)
    assert fragment in e.message, str(e)
    assert (e.line, e.col) == (line, col), str(e)
    assert e.exit_code == 2
    lines = str(e).splitlines()
    assert lines[0] == f"t.lsys:{line}:{col}: {e.message}"
    assert lines[1] == text.splitlines()[line - 1]
    assert lines[2].endswith("^") and len(lines[2]) == col


def test_undeclared_modules_are_plain_modules() -> None:
    c = compile_grammar("Axiom: A Foo Bar(1, 2)\nA --> Bar(3, 4) Z\n")
    assert c.program().arity == {"A": 0, "Foo": 0, "Bar": 2, "Z": 0}


def test_name_splitting() -> None:
    src = "derivation length: 2\nAxiom: X\nX --> FF[+X]FX Leaf F(2)X\n"
    prog = compile_grammar(src).program()

    class Ctx:
        pass

    names = [m[0] for m in prog.productions["X"](Ctx())]
    assert names == ["F", "F", "[", "+", "X", "]", "F", "X", "Leaf", "F", "X"]
    # a declared multi-letter module is one module; its letters are not split
    src2 = "module AB\nAxiom: AB BA\nA --> F\nB --> F\n"
    axiom = compile_grammar(src2).program().axiom(Ctx())
    assert [m[0] for m in axiom] == ["AB", "B", "A"]


def test_probabilities_within_tolerance() -> None:
    c = compile_grammar("Axiom: A\nA --> F : 1/3\nA --> G : 1/3\nA --> H : 1/3\n")
    assert c.sites[0].probs == pytest.approx((1 / 3,) * 3)
    compile_grammar("Axiom: A\nA --> F : 0.66\nA --> G : 0.34\n")  # 0.66 + 0.34 != 1.0 exactly
    compile_grammar("Axiom: A\nA --> F : 1\n")  # a single alternative may say 1
    compile_grammar("Axiom: A\nA --> F : 0\nA --> G : 1\n")  # zero is a valid probability


def test_site_table_of_vines() -> None:
    c = compile_grammar(VINES, filename="grammars/vines.lsys")
    ids = [s.id for s in c.sites]
    assert ids == [
        "S/0/normal0",
        "B/0/normal0",
        "L/choice",
        "Lf/0/normal0",
        "P/choice",
        "T/choice",
        "C1/choice",
        "C2/choice",
    ]
    s = c.sites[2]
    assert (s.kind, s.k, s.module, s.arity) == ("categorical", 3, "L", 0)
    b = c.sites[1]
    assert (b.kind, b.module, b.arity, b.source) == ("normal", "B", 1, "gauss(0, 22.5)")
    assert VINES.splitlines()[b.line - 1][b.col - 1 :].startswith("gauss(0, 22.5)")
    assert c.sites[6].probs == (0.66, 0.34)


def test_site_ids_with_conditions_and_axiom() -> None:
    src = (
        "derivation length: 3\nAxiom: F(uniform(0, 1)) A(1)\n"
        "A(x) : x > 1 --> F(gauss(0, 1)) : 0.5\nA(x) : x > 1 --> F(gauss(0, 2)) : 0.5\n"
        "A(x) --> F(gauss(x, 1)) F(gauss(x, 1)) A(x + 1)\n"
    )
    ids = [s.id for s in compile_grammar(src).sites]
    assert ids == [
        "axiom/uniform0",
        "A(x>1)/choice",
        "A(x>1)/0/normal0",
        "A(x>1)/1/normal0",
        "A/0/normal0",
        "A/0/normal1",
    ]


def edit(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new)


@pytest.mark.parametrize(
    "old,new",
    [
        ("P --> @O(FLOWER) : 0.5\nP --> * : 0.5", "P --> @O(FLOWER) : 0.25\nP --> * : 0.75"),
        ("Lf(s) --> [", "Q(z) --> F(uniform(0, 1))\nZ --> F(gauss(0, 1)) : 1\nLf(s) --> ["),
        ("S --> +(gauss(0, 30)) B(W0)", "S --> +(gauss(0, 30)) +(uniform(-5, 5)) B(W0)"),
        ("#define LEN 2", "# a new comment line\n\n#define LEN 2.5\n#define EXTRA 3"),
        ("production:\n", "production:\nNew(a) --> F(flip(0.5))\n"),
    ],
)
def test_site_ids_are_stable_under_unrelated_edits(old: str, new: str) -> None:
    before = {s.id: s for s in compile_grammar(VINES).sites}
    after = {s.id: s for s in compile_grammar(edit(VINES, old, new)).sites}
    # every site of an unedited rule keeps its id (indices and lines may move)
    for sid in ("B/0/normal0", "L/choice", "Lf/0/normal0", "T/choice", "C1/choice", "C2/choice"):
        assert sid in after
        assert (after[sid].kind, after[sid].k, after[sid].source) == (
            before[sid].kind,
            before[sid].k,
            before[sid].source,
        )
    assert [s.index for s in compile_grammar(edit(VINES, old, new)).sites] == list(
        range(len(after))
    )


def test_alternative_order_and_ordinals_define_ids() -> None:
    src = "Axiom: A\nA --> F(gauss(0, 1)) F(uniform(0, 1)) F(gauss(0, 2)) : 0.5\nA --> * : 0.5\n"
    ids = [s.id for s in compile_grammar(src).sites]
    assert ids == ["A/choice", "A/0/normal0", "A/0/uniform0", "A/0/normal1"]


def test_deep_nesting_is_a_grammar_error() -> None:
    for inner in ("-" * 3000 + "1", "sin(" * 150 + "1" + ")" * 150, "1+" * 5000 + "1"):
        assert "nested too deeply" in err(f"Axiom: F({inner})\n").message


def test_rules_before_any_section_are_productions() -> None:
    prog = compile_grammar("Axiom: A\nA --> F\n").program()
    assert set(prog.productions) == {"A"} and prog.interpretation == {}


# ---- issue #27: what Python cannot compile, and runaway headers, are grammar errors --------


@pytest.mark.parametrize(
    "text, line, col, words",
    [
        # Python reads at most 200 nested brackets: sin() prints two per level
        (
            "Axiom: F(1)\nA --> F(2) F(" + "sin(" * 100 + "1" + ")" * 100 + ")\n",
            2,
            14,
            "expression nested too deeply for Python (200 levels of parentheses",
        ),
        (
            "derivation length: 1\nAxiom: A(1)\nA(x) : "
            + "cos(x and " * 50
            + "x"
            + ")" * 50
            + " --> F\n",
            3,
            8,
            "expression nested too deeply for Python",
        ),
        (
            "Axiom: F(1)\n#define K " + "-" * 150 + "1\n",
            2,
            112,
            "expression nested too deeply: more than 100 levels",
        ),
        ("Axiom: F(" + "1 + " * 400 + "1)\n", 1, 10, "more than 100 levels"),
    ],
)
def test_nesting_errors_name_the_place_and_cause(
    text: str, line: int, col: int, words: str
) -> None:
    """Finding 8: every nesting Python could not compile was "nested too deeply" at 1:1."""
    e = err(text)
    assert words in e.message and (e.line, e.col) == (line, col), e


@pytest.mark.parametrize(
    "header, value",
    [("derivation length", "1e9"), ("max primitives", "1e18"), ("max modules", "1e12")],
)
def test_absurd_header_values_are_errors(header: str, value: str) -> None:
    """Finding 3: `max primitives: 1e18` with `derivation length: 1e9` ran without end."""
    e = err(f"{header}: {value}\nAxiom: F\n")
    assert f"'{header}:' must be at most" in e.message and f"got {float(value):g}" in e.message
    assert (e.line, e.col) == (1, len(header) + 3)
    compile_grammar(f"{header}: 1000\nAxiom: F\n")  # ordinary values stay fine


def test_polygon_closed_without_an_opening_is_an_error() -> None:
    e = err("Axiom: A\nA --> F . } F\n")
    assert "unmatched '}' in rule for A: no '{' before it" in e.message and (e.line, e.col) == (
        2,
        11,
    )
    compile_grammar("Axiom: A\nA --> { . F . } [ { . ]\n")


# --- 3D (docs/language.md section 4.1) ------------------------------------------------------


@pytest.mark.parametrize(
    "text",
    [
        "Axiom: F & F\n",
        "Axiom: F ^(10) F\n",
        "Axiom: F \\ F\n",
        "Axiom: F / F\n",
        "Axiom: F $ F\n",
        "Axiom: @Tp(0, -1, 0) F\n",
        "Axiom: @Ts(0.2) F\n",
        "Axiom: A\nA --> F [/ F]\n",
        "Axiom: A\ninterpretation:\nA --> F & F\n",
        "tropism: 0 -1 0 0.2\nAxiom: F\n",
        "dimensions: 3\nAxiom: F\n",
        "viewport: -1 1 -1 1 -1 1\nAxiom: F\n",
    ],
)
def test_what_makes_a_grammar_3d(text: str) -> None:
    assert compile_grammar(text).checked.dim == 3


@pytest.mark.parametrize(
    "text",
    [
        "Axiom: F + F - F | F\n",
        "Axiom: F ; F , F ;(2)\n",
        "dimensions: 2\nAxiom: F ; F\n",
        "viewport: -1 1 -1 1\nAxiom: F(2 ^ 2 / 2)\n",
    ],
)
def test_2d_grammars_stay_2d(text: str) -> None:
    assert compile_grammar(text).checked.dim == 2


ERRORS_3D = [
    (
        "dimensions: 2\nAxiom: F & F\n",
        "the 3D symbol '&' needs a 3D grammar, but 'dimensions: 2' says this one is 2D",
        2,
        10,
    ),
    ("dimensions: 2\ntropism: 0 -1 0 1\nAxiom: F\n", "'tropism:' needs a 3D grammar", 2, 1),
    ("dimensions: 2\nviewport: 0 1 0 1 0 1\nAxiom: F\n", "a viewport of 6 numbers", 2, 1),
    ("dimensions: 4\nAxiom: F\n", "'dimensions:' must be 2 or 3, got 4", 1, 13),
    (
        "viewport: 0 1 0 1\nAxiom: A\nA --> F / F\n",
        "this grammar is 3D (the 3D symbol '/' at line 3:9), so its viewport is a box of 6 numbers",
        1,
        1,
    ),
    ("dimensions: 3\nviewport: 0 1 0 1\nAxiom: F\n", "('dimensions: 3' at line 1:1)", 2, 1),
    ("viewport: 0 1 0 1 1 0\nAxiom: F\n", "xmin < xmax and ymin < ymax and zmin < zmax", 1, 1),
    ("tropism: 0 0 0 0.5\nAxiom: F\n", "'tropism:' needs a direction other than 0 0 0", 1, 1),
    ("tropism: 0 -1 0 (uniform(0, 1))\nAxiom: F\n", "not allowed in 'tropism:'", 1, 18),
    ("Axiom: @Tp(1, 2)\n", "turtle symbol @Tp takes 3 arguments, got 2", 1, 8),
    ("Axiom: @Ts\n", "turtle symbol @Ts takes 1 argument, got 0", 1, 8),
    ("Axiom: &(1, 2)\n", "turtle symbol & takes 0 to 1 arguments, got 2", 1, 8),
    ("Axiom: ;(1, 2)\n", "turtle symbol ; takes 0 to 1 arguments, got 2", 1, 8),
    ("Axiom: A\n/ --> F\n", "unexpected '/'", 2, 1),
    ("Axiom: @Tx\n", "the @ symbols are @O (disk or sphere), @Tp and @Ts", 1, 8),
]


@pytest.mark.parametrize(("text", "fragment", "line", "col"), ERRORS_3D)
def test_3d_errors_name_the_place(text: str, fragment: str, line: int, col: int) -> None:
    e = err(text)
    assert fragment in str(e), str(e)
    assert (e.line, e.col) == (line, col), str(e)
    assert str(e).startswith(f"t.lsys:{line}:{col}: ") and str(e).splitlines()[-1].endswith("^")


def test_3d_headers_and_defaults() -> None:
    c = compile_grammar(
        "angle: 30\nviewport: -1 1 -2 2 -3 3\ntropism: 0, -2, 0, 0.3\n"
        "Axiom: & ^(10) \\ / ; , ;(3) ~l @O F\n"
    ).checked
    assert (c.dim, c.box, c.viewport) == (3, (-1, 1, -2, 2, -3, 3), (-1, 1, -2, 2))
    assert c.tropism == (0.0, -1.0, 0.0, 0.3)  # a unit direction
    got = [(m.name, [a.value for a in m.args]) for m in c.axiom]
    assert got == [
        ("&", [30.0]),
        ("^", [10.0]),
        ("\\", [30.0]),
        ("/", [30.0]),
        (";", []),
        (",", []),
        (";", [3.0]),
        ("~l", [1.0, 1.0]),
        ("@O", [1.0]),
        ("F", [1.0]),
    ]
