"""Persistent cons lists `(head, rest)` / `None`: the particles' stacks, polygons and drawn
primitives, shared between particles and never copied (architecture.md section 3)."""

from __future__ import annotations

from typing import Any

Cons = tuple[Any, Any]  # a cons list node (head, rest); rest is a Cons or None


def cons_to_list(node: Cons | None) -> list[Any]:
    """A cons list `(head, rest)` (newest first) as a Python list, oldest first."""
    out = []
    while node is not None:
        out.append(node[0])
        node = node[1]
    out.reverse()
    return out
