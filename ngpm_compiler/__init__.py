"""ngpm_compiler: the .lsys language, code generation, training and export (CLI `ngpmc`).

Python API (see docs/api.md):

    from ngpm_compiler import compile_grammar
    program = compile_grammar("grammars/vines.lsys").program()

The names below are imported on first use, so `import ngpm_compiler` stays cheap.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_EXPORTS = {
    "compile_grammar": "ngpm_compiler.language.compile",
    "CompiledGrammar": "ngpm_compiler.language.compile",
    "write_compiled": "ngpm_compiler.language.compile",
    "GrammarError": "ngpm_compiler.language.errors",
    "load_grammar": "ngpm_compiler.language.compile",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'ngpm_compiler' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
