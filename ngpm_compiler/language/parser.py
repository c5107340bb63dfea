"""Parse .lsys text into nodes (lark LALR parser, grammar in lsys.lark)."""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

from lark import Lark, Token, Tree
from lark.exceptions import UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken

from ngpm_compiler.language.errors import ErrorSink, GrammarError
from ngpm_compiler.language.nodes import (
    Binary,
    Call,
    Define,
    Expr,
    Grammar,
    Header,
    ModuleDecl,
    ModuleUse,
    Num,
    Rule,
    Successor,
    Unary,
    Var,
)

# How an expected terminal reads in an error message.
TERMINAL_NAMES = {
    "NAME": "a name",
    "NUMBER": "a number",
    "ARROW": "'-->'",
    "_NL": "end of line",
    "$END": "end of file",
    "COLON": "':'",
    "LPAR": "'('",
    "RPAR": "')'",
    "COMMA": "','",
    "EQUAL": "'='",
    "STAR": "'*'",
    "ALT": "'|'",
    "ALT_NL": "'|'",
    "SPECIAL": "'~l' or '@O'",
    "OR": "'or'",
    "AND": "'and'",
    "NOT": "'not'",
    "CMP": "a comparison",
    "ADD": "'+' or '-'",
    "MUL": "'*', '/' or '%'",
    "POW": "'^'",
    "MINUS": "'-'",
    "PLUS": "'+'",
    "LSQB": "'['",
    "RSQB": "']'",
    "BANG": "'!'",
    "LBRACE": "'{'",
    "DOT": "'.'",
    "RBRACE": "'}'",
    "PERCENT": "'%'",
    "MODULE": "'module'",
    "ENDLSYSTEM": "'endlsystem'",
    "HASH_DEFINE": "'#define'",
    "DEFINE": "'define:'",
    "AXIOM": "'Axiom:'",
    "DERIVATION_LENGTH": "'derivation length:'",
    "PRODUCTION": "'production:'",
    "INTERPRETATION": "'interpretation:'",
    "VIEWPORT": "'viewport:'",
    "ANGLE": "'angle:'",
    "START": "'start:'",
    "MAX_PRIMITIVES": "'max primitives:'",
    "MAX_MODULES": "'max modules:'",
    "TROPISM": "'tropism:'",
    "DIMENSIONS": "'dimensions:'",
    "TURTLE_ARGUMENTS": "'turtle arguments:'",
    "AMPERSAND": "'&'",
    "CIRCUMFLEX": "'^'",
    "BACKSLASH": "'\\'",
    "SLASH": "'/'",
    "DOLLAR": "'$'",
    "SEMICOLON": "';'",
}
# Terminals of the 3D language and its headers, left out of a syntax error's list of what
# was expected, so the messages read as they did before 3D (lists are cut at six anyway).
UNLISTED = {
    "TURTLE_ARGUMENTS",
    "TROPISM",
    "DIMENSIONS",
    "AMPERSAND",
    "CIRCUMFLEX",
    "BACKSLASH",
    "SLASH",
    "DOLLAR",
    "SEMICOLON",
}
# A viewport line cut short (5 numbers, say): the message says what it takes.
VIEWPORT_LINE = re.compile(r"\s*viewport\s*:", re.I)
VIEWPORT_COUNT = (
    "'viewport:' takes 4 numbers (xmin xmax ymin ymax), or 6 for a 3D grammar "
    "(xmin xmax ymin ymax zmin zmax)"
)
# Deepest expression (nodes from the top, each operator and call one level): deeper ones are
# an error, so the recursive passes over expressions stay within Python's recursion limit.
MAX_EXPR_DEPTH = 100
# Section names the module-level statements use.
HEADER_KINDS = {
    "derivation_length": "derivation length",
    "viewport": "viewport",
    "angle": "angle",
    "start_pose": "start",
    "max_primitives": "max primitives",
    "max_modules": "max modules",
    "tropism": "tropism",
    "dimensions": "dimensions",
    "turtle_arguments": "turtle arguments",
}


@lru_cache(maxsize=1)
def lark_parser() -> Lark:
    text = (Path(__file__).with_name("lsys.lark")).read_text()
    return Lark(
        text, parser="lalr", lexer="contextual", propagate_positions=True, maybe_placeholders=False
    )


def parse(source: str, filename: str = "<grammar>") -> Grammar:
    """Parse a grammar's text; raise GrammarError on a syntax error."""
    sink = ErrorSink(filename, source)
    try:
        tree = lark_parser().parse(source)
    except UnexpectedInput as err:
        raise syntax_error(err, sink, source) from None
    return Builder(sink, source).grammar(tree)


def _expected(names: set[str]) -> str:
    hidden = UNLISTED | ({"COMMA"} if "LSQB" in names else set())  # `,` in a successor
    words = sorted(
        {TERMINAL_NAMES.get(n, n) for n in names if not n.startswith("__") and n not in hidden}
    )
    if not words:
        return ""
    if len(words) > 6:
        words = words[:6] + ["..."]
    return "expected " + (words[0] if len(words) == 1 else "one of " + ", ".join(words))


def syntax_error(err: UnexpectedInput, sink: ErrorSink, source: str) -> GrammarError:
    """Turn lark's exception into a one-line human message with a position."""
    line, col = getattr(err, "line", 1), getattr(err, "column", 1)
    if isinstance(err, UnexpectedEOF) or line in (None, -1):
        lines = source.splitlines() or [""]
        return sink.error("unexpected end of file", len(lines), len(lines[-1]) + 1)
    if isinstance(err, UnexpectedToken):
        text = str(err.token)
        expected = set(err.expected)
        if err.token.type == "$END":
            lines = source.splitlines() or [""]
            return sink.error(
                f"unexpected end of file, {_expected(expected)}", len(lines), len(lines[-1]) + 1
            )
        if err.token.type in ("_NL", "ALT_NL"):
            if VIEWPORT_LINE.match(source.splitlines()[line - 1]):
                return sink.error(VIEWPORT_COUNT, line, col)
            return sink.error(f"unexpected end of line, {_expected(expected)}", line, col)
    else:
        assert isinstance(err, UnexpectedCharacters)
        at = err.pos_in_stream
        text = source[at] if at is not None and at < len(source) else ""
        expected = set(err.allowed or ())
    first = text[:1]
    if first in "<>" and "ARROW" in expected:
        return sink.error("context-sensitive rules (A < B > C) are not supported", line, col)
    shown = text if text.strip() else repr(text)
    return sink.error(f"unexpected '{shown}', {_expected(expected)}".rstrip(", "), line, col)


class Builder:
    """Builds nodes from lark's tree."""

    def __init__(self, sink: ErrorSink, source: str) -> None:
        self.sink = sink
        self.source = source
        self.section = "production"
        self.ended: Tree[Token] | None = None

    def text(self, tree: Tree[Token] | Token) -> str:
        if isinstance(tree, Token):
            return str(tree)
        return self.source[tree.meta.start_pos : tree.meta.end_pos]

    def grammar(self, tree: Tree[Token]) -> Grammar:
        g = Grammar(self.sink.filename, self.source)
        for child in tree.children:
            if self.ended is not None:
                raise self.sink.error("text after 'endlsystem'", *pos(child))
            stmt = subtree(child)
            getattr(self, "stmt_" + stmt.data)(g, stmt)
        return g

    # ---- statements ----------------------------------------------------------------------

    def stmt_hash_define(self, g: Grammar, t: Tree[Token]) -> None:
        _, name, expr = t.children
        g.defines.append(Define(*pos(name), str(name), self.expr(expr), self.text(t)))

    def stmt_define(self, g: Grammar, t: Tree[Token]) -> None:
        kids = t.children[1:]
        for name, expr in zip(kids[0::2], kids[1::2], strict=True):
            g.defines.append(
                Define(*pos(name), str(name), self.expr(expr), f"{name} = {self.text(expr)}")
            )

    def stmt_module_decl(self, g: Grammar, t: Tree[Token]) -> None:
        for decl in t.children:
            if not isinstance(decl, Tree):
                continue
            name = decl.children[0]
            params = self.params(subtree(decl.children[1])) if len(decl.children) > 1 else []
            g.decls.append(ModuleDecl(*pos(name), str(name), [p for p, _ in params]))

    def stmt_axiom(self, g: Grammar, t: Tree[Token]) -> None:
        if g.axiom is not None:
            raise self.sink.error("a second 'Axiom:' line", *pos(t))
        g.axiom = self.successor(subtree(t.children[1]))

    def stmt_section(self, g: Grammar, t: Tree[Token]) -> None:
        word = str(t.children[0]).lower()
        self.section = "production" if word.startswith("production") else "interpretation"

    def stmt_endlsystem(self, g: Grammar, t: Tree[Token]) -> None:
        self.ended = t

    def _header(self, g: Grammar, t: Tree[Token]) -> None:
        kind = HEADER_KINDS[t.data]
        if kind in g.headers:
            raise self.sink.error(f"a second '{kind}:' line", *pos(t))
        values = [
            self.expr(c)
            for c in t.children[1:]
            if isinstance(c, Tree | Token) and not (isinstance(c, Token) and c.type in ("COMMA",))
        ]
        g.headers[kind] = Header(*pos(t), kind, values)

    stmt_derivation_length = stmt_viewport = stmt_angle = _header
    stmt_start_pose = stmt_max_primitives = stmt_max_modules = _header
    stmt_tropism = stmt_dimensions = stmt_turtle_arguments = _header

    def stmt_rule(self, g: Grammar, t: Tree[Token]) -> None:
        kids = t.children
        pred_tree, alts_tree = subtree(kids[0]), subtree(kids[-1])
        cond_tree = kids[1] if len(kids) == 4 else None
        name = pred_tree.children[0]
        params = self.params(subtree(pred_tree.children[1])) if len(pred_tree.children) > 1 else []
        cond = self.expr(cond_tree) if cond_tree is not None else None
        cond_text = self.text(cond_tree) if cond_tree is not None else ""
        pairs: list[tuple[Tree[Token] | Token, Tree[Token] | Token | None]]
        if alts_tree.data == "plain":
            pairs = [(alts_tree.children[0], None)]
        else:
            pairs = [
                (w.children[0], w.children[1]) for w in alts_tree.children if isinstance(w, Tree)
            ]
        rule_text = self.text(t)
        for succ, prob in pairs:
            g.rules.append(
                Rule(
                    *pos(name),
                    str(name),
                    [p for p, _ in params],
                    [q for _, q in params],
                    cond,
                    cond_text,
                    self.successor(subtree(succ)),
                    self.expr(prob) if prob is not None else None,
                    self.section,
                    rule_text,
                    t.meta.end_line,
                )
            )

    # ---- parts ---------------------------------------------------------------------------

    def params(self, t: Tree[Token]) -> list[tuple[str, tuple[int, int]]]:
        return [(str(p), pos(p)) for p in t.children if isinstance(p, Token)]

    def successor(self, t: Tree[Token]) -> Successor:
        line, col = pos(t)
        if t.data == "delete":
            return Successor(line, col, [], "*")
        mods = []
        for child in t.children:
            item = subtree(child)
            head = item.children[0]
            if isinstance(head, Tree):  # a turtle symbol
                head = head.children[0]
            args = subtree(item.children[1]) if len(item.children) > 1 else None
            mods.append(
                ModuleUse(
                    *pos(head),
                    str(head),
                    [self.expr(a) for a in args.children] if args is not None else [],
                    args is not None,
                )
            )
        return Successor(line, col, mods, self.text(t) if t.children else "")

    def expr(self, t: Tree[Token] | Token, depth: int = 0) -> Expr:
        """The expression node of `t`; `depth` counts the nodes above it (at most
        MAX_EXPR_DEPTH, which keeps every recursive pass over expressions in bounds)."""
        line, col = pos(t)
        if depth > MAX_EXPR_DEPTH:
            raise self.sink.error(
                f"expression nested too deeply: more than {MAX_EXPR_DEPTH} "
                "levels (each operator and call is a level)",
                line,
                col,
            )
        if isinstance(t, Token):  # a lone token (only NUMBER / NAME reach here), at its place
            kind = "number" if t.type == "NUMBER" else "var"
            kids: list[Token | Tree[Token]] = [t]
        else:
            kind, kids = t.data, t.children

        def sub(node: Tree[Token] | Token) -> Expr:
            return self.expr(node, depth + 1)

        if kind == "number":
            try:
                return Num(line, col, float(str(kids[0])))
            except OverflowError:  # pragma: no cover - float() returns inf, not raises
                raise self.sink.error("number too large", line, col) from None
        if kind == "var":
            return Var(line, col, str(kids[0]))
        if kind == "neg":
            return Unary(line, col, "-", sub(kids[0]))
        if kind == "unary":
            return Unary(line, col, str(kids[0]), sub(kids[1]))
        if kind == "not_":
            return Unary(line, col, "not", sub(kids[1]))
        if kind in ("binary", "compare"):
            op = str(kids[1])
            return Binary(*pos(kids[1]), "^" if op == "**" else op, sub(kids[0]), sub(kids[2]))
        if kind in ("or_", "and_"):
            return Binary(*pos(kids[1]), kind[:-1], sub(kids[0]), sub(kids[2]))
        if kind == "call":
            return Call(line, col, str(kids[0]), [sub(a) for a in kids[1:]], self.text(t))
        raise self.sink.error(f"unexpected expression ({kind})", line, col)  # pragma: no cover


def subtree(node: Tree[Token] | Token) -> Tree[Token]:
    """`node`, where lsys.lark puts a rule (never a token) at that place."""
    assert isinstance(node, Tree), f"a rule expected, not {node!r}"
    return node


def pos(t: Tree[Token] | Token) -> tuple[int, int]:
    if isinstance(t, Token):
        return t.line or 1, t.column or 1
    if t.meta.empty:
        return 1, 1
    return t.meta.line, t.meta.column
