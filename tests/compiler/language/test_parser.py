"""The .lsys syntax: headers, rules, alternatives, comments and syntax-error messages."""

from __future__ import annotations

import pytest

from ngpm_compiler.language.errors import GrammarError
from ngpm_compiler.language.nodes import Binary, Call, Num, Unary, Var
from ngpm_compiler.language.parser import parse


def err(text: str) -> GrammarError:
    with pytest.raises(GrammarError) as info:
        parse(text, "t.lsys")
    return info.value


def test_headers_defines_and_comments() -> None:
    g = parse(
        "# a comment\n#define A 2   # trailing comment\ndefine: B = A * 3, C = -1\n"
        "module X(a, b), Y\n\n  # indented comment\nviewport: -1, 2 -3 (4)\nangle: 22.5\n"
        "start: 0 -1 90\nmax primitives: 100\nderivation length: 7\nAxiom: X(1, 2) Y\n"
        "production:\nY --> F\nhomomorphism:\nX(a, b) --> F(a)\nendlsystem\n\n# done\n",
        "t.lsys",
    )
    assert [d.name for d in g.defines] == ["A", "B", "C"]
    assert isinstance(g.defines[1].expr, Binary) and g.defines[1].expr.op == "*"
    assert [(d.name, d.params) for d in g.decls] == [("X", ["a", "b"]), ("Y", [])]
    assert sorted(g.headers) == [
        "angle",
        "derivation length",
        "max primitives",
        "start",
        "viewport",
    ]
    assert len(g.headers["viewport"].values) == 4 and len(g.headers["start"].values) == 3
    assert [m.name for m in g.axiom.modules] == ["X", "Y"]
    assert [(r.pred, r.section) for r in g.rules] == [("Y", "production"), ("X", "interpretation")]


def test_rule_parts() -> None:
    g = parse(
        "Axiom: A(1)\nA(x, y) : x > 1 and not y --> F(x) [ +(-30) A(x - 1, y) ] : 1\n", "t.lsys"
    )
    r = g.rules[0]
    assert (r.pred, r.params, r.cond_text, r.line, r.col) == (
        "A",
        ["x", "y"],
        "x > 1 and not y",
        2,
        1,
    )
    assert isinstance(r.cond, Binary) and r.cond.op == "and"
    assert [m.name for m in r.successor.modules] == ["F", "[", "+", "A", "]"]
    plus = r.successor.modules[2]
    assert isinstance(plus.args[0], Unary) and plus.args[0].op == "-"
    assert isinstance(r.prob, Num) and r.prob.value == 1.0


def test_alternatives_on_one_line_and_continued() -> None:
    one = parse("Axiom: F\nF --> F[+F]F[-F]F : 1/3 | F[+F]F : 1/3 | F[-F]F : 1/3\n", "t")
    more = parse(
        "Axiom: F\nF --> F[+F]F[-F]F : 1/3\n  # note\n    | F[+F]F : 1/3\n    | F[-F]F : 1/3\n", "t"
    )
    for g in (one, more):
        assert len(g.rules) == 3 and all(r.pred == "F" for r in g.rules)
        assert [len(r.successor.modules) for r in g.rules] == [11, 6, 6]


def test_bar_is_turn_around_without_probabilities() -> None:
    g = parse("Axiom: A\nA --> F | F\n", "t")
    assert [m.name for m in g.rules[0].successor.modules] == ["F", "|", "F"]


def test_empty_successors() -> None:
    g = parse("Axiom: A\nA --> * : 0.5\nA --> : 0.5\nB -->\n", "t")
    assert [r.successor.modules for r in g.rules] == [[], [], []]


def test_expression_precedence() -> None:
    g = parse("Axiom: F(1 + 2 * 3 ^ 2 ^ 2 - -4 % 3)\n", "t")
    e = g.axiom.modules[0].args[0]
    assert isinstance(e, Binary) and e.op == "-"
    mul = e.left.right
    assert mul.op == "*" and mul.right.op == "^" and mul.right.right.op == "^"
    call = parse("Axiom: F(atan2(1, x))\n", "t").axiom.modules[0].args[0]
    assert isinstance(call, Call) and call.text == "atan2(1, x)"
    assert isinstance(call.args[1], Var)


def test_syntax_error_format() -> None:
    e = err("Axiom: A\nA -- F\n")
    assert str(e) == ("t.lsys:2:3: unexpected '-', expected one of '(', '-->', ':'\nA -- F\n  ^")
    assert e.exit_code == 2 and (e.line, e.col) == (2, 3)


def test_syntax_error_messages() -> None:
    assert "unexpected end of line, expected" in str(err("Axiom: A\nA --> F(1,\n"))
    assert "unexpected end of file" in str(err("Axiom: A\nA --> F("))
    assert "unexpected '?'" in str(err("Axiom: A\nA --> F(1 ? 2)\n"))
    assert "expected" in str(err("Axiom: A\nA --> B\n  : 0.5\n"))
    caret = str(err("Axiom: A\n\tA --> F(1 ? 2)\n")).splitlines()
    assert caret[-1] == "\t" + " " * 10 + "^"


@pytest.mark.parametrize("sym", ["&", "^", "\\", "/", "$", ";", ","])
def test_3d_symbols_parse(sym: str) -> None:
    g = parse(f"Axiom: A\nA --> F {sym} F{sym}(2) [{sym}F]\n", "t")
    mods = g.rules[0].successor.modules
    assert [m.name for m in mods] == ["F", sym, "F", sym, "[", sym, "F", "]"]
    assert (mods[1].line, mods[1].col) == (2, 9) and not mods[1].args
    assert isinstance(mods[3].args[0], Num) and mods[3].args[0].value == 2.0


def test_3d_symbols_beside_expressions() -> None:
    """`^`, `/` and `,` are operators and separators inside arguments and probabilities,
    turtle symbols between modules."""
    g = parse("Axiom: F(2 ^ 3 / 4, 1)/(90 / 2)^F,F\nF --> F/F : 1/2 | F^F : 1/2\n", "t")
    assert [m.name for m in g.axiom.modules] == ["F", "/", "^", "F", ",", "F"]
    assert g.axiom.modules[0].args[0].op == "/" and len(g.axiom.modules[0].args) == 2
    assert [[m.name for m in r.successor.modules] for r in g.rules] == [
        ["F", "/", "F"],
        ["F", "^", "F"],
    ]


def test_3d_headers_and_tropism_symbols() -> None:
    g = parse(
        "dimensions: 3\ntropism: 0, -1, 0, 0.22\nviewport: -1 1 -2 2 (-3) 3\n"
        "Axiom: @Tp(1, 0, 0) @Ts(0.1) @O\n",
        "t",
    )
    assert [len(g.headers[k].values) for k in ("dimensions", "tropism", "viewport")] == [1, 4, 6]
    assert [m.name for m in g.axiom.modules] == ["@Tp", "@Ts", "@O"]


def test_3d_symbols_out_of_place_and_short_viewports() -> None:
    assert "unexpected '&'" in str(err("Axiom: A\n& --> F\n"))
    e = err("viewport: 1 2 3 4 5\nAxiom: A\n")
    assert "'viewport:' takes 4 numbers" in str(e) and (e.line, e.col) == (1, 20)
    assert "unexpected '7'" in str(err("viewport: 1 2 3 4 5 6 7\nAxiom: A\n"))


@pytest.mark.parametrize("rule", ["A < B --> F", "B > A --> F", "A(x) < B --> F"])
def test_context_sensitive_rules_are_rejected(rule: str) -> None:
    assert "context-sensitive rules" in str(err(f"Axiom: A\n{rule}\n"))


def test_second_axiom_and_text_after_end() -> None:
    assert "second 'Axiom:'" in str(err("Axiom: A\nAxiom: B\n"))
    assert "second 'angle:'" in str(err("angle: 1\nangle: 2\nAxiom: A\n"))
    assert "after 'endlsystem'" in str(err("Axiom: A\nendlsystem\nA --> B\n"))
