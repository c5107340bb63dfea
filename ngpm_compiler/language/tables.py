"""Built-in tables of the language: operators, functions, random calls, turtle symbols.

A leaf module: the checker and the code generator both read these, and it imports nothing
of theirs.
"""

from __future__ import annotations

from collections.abc import Callable

# Python precedence of each operator (higher binds tighter).
PREC = {
    "or": 1,
    "and": 2,
    "not": 3,
    "<": 4,
    "<=": 4,
    ">": 4,
    ">=": 4,
    "==": 4,
    "!=": 4,
    "+": 5,
    "-": 5,
    "*": 6,
    "/": 6,
    "%": 6,
    "neg": 7,
    "atom": 9,
}
BOOL_OPS = {"or", "and", "not", "<", "<=", ">", ">=", "==", "!="}

# Math functions: templates over the printed arguments. Angles are degrees.
FUNC_TEMPLATES: dict[str, Callable[[list[str]], str]] = {
    "sin": lambda a: f"math.sin(math.radians({a[0]}))",
    "cos": lambda a: f"math.cos(math.radians({a[0]}))",
    "tan": lambda a: f"math.tan(math.radians({a[0]}))",
    "asin": lambda a: f"math.degrees(math.asin({a[0]}))",
    "acos": lambda a: f"math.degrees(math.acos({a[0]}))",
    "atan": lambda a: f"math.degrees(math.atan({a[0]}))",
    "atan2": lambda a: f"math.degrees(math.atan2({a[0]}, {a[1]}))",
    "sqrt": lambda a: f"math.sqrt({a[0]})",
    "exp": lambda a: f"math.exp({a[0]})",
    "log": lambda a: f"math.log({a[0]})",
    "pow": lambda a: f"math.pow({a[0]}, {a[1]})",
    "abs": lambda a: f"abs({a[0]})",
    "min": lambda a: f"min({', '.join(a)})",
    "max": lambda a: f"max({', '.join(a)})",
    "floor": lambda a: f"float(math.floor({a[0]}))",
    "ceil": lambda a: f"float(math.ceil({a[0]}))",
    "round": lambda a: f"float(math.floor({a[0]} + 0.5))",
}
# (min args, max args or None) of every function, random ones included.
FUNCTION_ARITY: dict[str, tuple[int, int | None]] = {
    "sin": (1, 1),
    "cos": (1, 1),
    "tan": (1, 1),
    "asin": (1, 1),
    "acos": (1, 1),
    "atan": (1, 1),
    "atan2": (2, 2),
    "sqrt": (1, 1),
    "exp": (1, 1),
    "log": (1, 1),
    "pow": (2, 2),
    "abs": (1, 1),
    "min": (2, None),
    "max": (2, None),
    "floor": (1, 1),
    "ceil": (1, 1),
    "round": (1, 1),
}
# Random calls: name -> (site kind, min args, max args or None)
RANDOM_CALLS: dict[str, tuple[str, int, int | None]] = {
    "gauss": ("normal", 2, 2),
    "normal": ("normal", 2, 2),
    "uniform": ("uniform", 2, 2),
    "flip": ("bernoulli", 1, 1),
    "bernoulli": ("bernoulli", 1, 1),
    "categorical": ("categorical", 2, None),
    "choice": ("categorical", 2, None),
}
BUILTIN_NAMES = {"pi": "math.pi"}

# Turtle symbols: (min args, max args, defaults of the optional ones). "angle" stands for the
# `angle:` header's value.
TURTLE: dict[str, tuple[int, int, tuple[float | str, ...]]] = {
    "F": (0, 1, (1.0,)),
    "f": (0, 1, (1.0,)),
    "+": (0, 1, ("angle",)),
    "-": (0, 1, ("angle",)),
    "|": (0, 0, ()),
    "[": (0, 0, ()),
    "]": (0, 0, ()),
    "!": (1, 1, ()),
    "~l": (0, 2, (1.0, 1.0)),
    "@O": (0, 1, (1.0,)),
    "{": (0, 0, ()),
    ".": (0, 0, ()),
    "}": (0, 0, ()),
    "%": (0, 0, ()),
    "halt": (0, 0, ()),
    # 3D (docs/language.md section 4.1); `;` and `,` without an argument step the colour
    "&": (0, 1, ("angle",)),
    "^": (0, 1, ("angle",)),
    "\\": (0, 1, ("angle",)),
    "/": (0, 1, ("angle",)),
    "$": (0, 0, ()),
    ";": (0, 1, ()),
    ",": (0, 1, ()),
    "@Tp": (3, 3, ()),
    "@Ts": (1, 1, ()),
}
REWRITABLE_TURTLE = {"F", "f"}  # turtle symbols a rule may rewrite
# Symbols only the 3D turtle has: a grammar that uses one is 3D.
TURTLE_3D = {"&", "^", "\\", "/", "$", "@Tp", "@Ts"}
