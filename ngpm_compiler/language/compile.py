"""`compile_grammar`: .lsys text -> generated sampler source, site table and Program."""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ngpm_runtime.files import atomic_write
from ngpm_runtime.program import Program, Site, load_program, run_generated

from ngpm_compiler.language.checker import Checked, check
from ngpm_compiler.language.codegen import generate
from ngpm_compiler.language.errors import GrammarError
from ngpm_compiler.language.parser import parse

# Grammars larger than this are refused before parsing (docs/language.md): checking takes
# about 3 s and 130 MB per 100 KiB (the parse tree); real grammars are a few KiB.
MAX_GRAMMAR_BYTES = 256 * 1024


@dataclass
class CompiledGrammar:
    name: str
    filename: str
    source_text: str
    source_code: str
    sites: list[Site]
    grammar_hash: str
    checked: Checked

    def sites_json(self) -> dict[str, Any]:
        return {
            "grammar": self.name,
            "grammar_hash": self.grammar_hash,
            "sites": [s.to_json() for s in self.sites],
        }

    def program(self) -> Program:
        """Execute the generated module and return its PROGRAM."""
        return run_generated(self.source_code, f"{self.name}_sampler.py")


def grammar_name(filename: str) -> str:
    stem = Path(filename).stem if filename and not filename.startswith("<") else "grammar"
    return "".join(c if c.isalnum() or c == "_" else "_" for c in stem) or "grammar"


def compile_grammar(
    path_or_text: str | os.PathLike[str], filename: str | None = None
) -> CompiledGrammar:
    """Compile a grammar given as a path or as its text; raise GrammarError if malformed.

    A str without a newline that ends in `.lsys` or names an existing file is a path."""
    _check_argument(path_or_text)
    text: str
    if isinstance(path_or_text, os.PathLike) or (
        isinstance(path_or_text, str)
        and "\n" not in path_or_text
        and (path_or_text.endswith(".lsys") or os.path.isfile(path_or_text))
    ):
        path = Path(path_or_text)
        if path.is_dir():
            raise GrammarError("is a folder, not a grammar file", str(path))
        if path.is_file() and path.stat().st_size > MAX_GRAMMAR_BYTES:
            raise GrammarError(_too_large(path.stat().st_size), str(path))
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise GrammarError("no such grammar file", str(path)) from None
        except UnicodeDecodeError:
            raise GrammarError("not a UTF-8 text file", str(path)) from None
        filename = filename or str(path_or_text)
    else:
        text = str(path_or_text)
        filename = filename or "<grammar>"
    text = text.replace("\r\n", "\n")
    if len(text) > MAX_GRAMMAR_BYTES:
        raise GrammarError(_too_large(len(text.encode("utf-8"))), filename)
    name = grammar_name(filename)
    digest = "sha256:" + hashlib.sha256(text.encode("utf-8")).hexdigest()
    checked = check(parse(text, filename), name)
    code = generate(checked, filename, digest)
    _python_compiles(code, name, filename)
    return CompiledGrammar(name, filename, text, code, checked.sites, digest, checked)


def _python_compiles(code: str, name: str, filename: str) -> None:
    """GrammarError if Python cannot compile the generated module. The checker and code
    generator refuse what Python cannot read (nesting, with its position), so this names a
    compiler bug rather than the grammar's."""
    try:
        compile(code, f"{name}_sampler.py", "exec")
    except SyntaxError as err:
        raise GrammarError(
            f"the generated Python does not compile ({err.msg}, line "
            f"{err.lineno} of {name}_sampler.py): an ngpmc bug, please report "
            "it with this grammar",
            filename,
        ) from None
    except (RecursionError, MemoryError) as err:
        raise GrammarError(
            f"the generated Python is too large for Python to compile ({type(err).__name__})",
            filename,
        ) from None


def _check_argument(path_or_text: object) -> None:
    """TypeError (or GrammarError, for a folder) unless compile_grammar can take it."""
    if isinstance(path_or_text, bytes | bytearray):
        raise TypeError(
            "compile_grammar wants a path or the grammar's text as str, got "
            "bytes: decode them first, e.g. data.decode('utf-8')"
        )
    if not isinstance(path_or_text, str | os.PathLike):
        raise TypeError(
            "compile_grammar wants a path (str or os.PathLike) or the grammar's "
            f"text (str), got {type(path_or_text).__name__}"
        )
    if (
        isinstance(path_or_text, str)
        and "\n" not in path_or_text
        and path_or_text.strip()
        and os.path.isdir(path_or_text)
    ):
        raise GrammarError("is a folder, not a grammar file", path_or_text)


def _too_large(size: int) -> str:
    return (
        f"the grammar is {size / 1024:.0f} KiB; ngpm reads grammars of up to "
        f"{MAX_GRAMMAR_BYTES // 1024} KiB"
    )


def write_compiled(compiled: CompiledGrammar, out_dir: str | os.PathLike[str]) -> tuple[Path, Path]:
    """Write `<name>_sampler.py` and `<name>_sites.json` into out_dir (atomically)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sampler = out / f"{compiled.name}_sampler.py"
    sites = out / f"{compiled.name}_sites.json"
    atomic_write(sampler, compiled.source_code)
    atomic_write(sites, json.dumps(compiled.sites_json(), indent=2) + "\n")
    return sampler, sites


def load_grammar(path: str | Path, text: str | None = None) -> Program:
    """A Program from a .lsys grammar (compiled here) or a generated sampler module.

    With `text`, the file's contents read elsewhere (e.g. by a cluster's driver): the same
    Program as from the file, without reading it."""
    path = Path(path)
    if path.suffix == ".py":
        return load_program(path, text)
    return compile_grammar(path if text is None else text, filename=str(path)).program()
