"""`ngpmc compile`, `ngpmc check` and `ngpmc sample`: grammar commands."""

from __future__ import annotations

import argparse
from pathlib import Path

from ngpm_runtime.errors import NgpmError

from ngpm_compiler.cli import argtypes
from ngpm_compiler.language.compile import (
    CompiledGrammar,
    compile_grammar,
    load_grammar,
    write_compiled,
)

# The help of every argument that takes a grammar, .lsys or generated (load_grammar).
GRAMMAR_HELP = ("the .lsys file, or a *_sampler.py written by `ngpmc compile`: that file is "
                "Python and runs when loaded, so give only samplers you trust (ngpm refuses "
                "other .py files without running them)")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("compile", help="compile a .lsys grammar into a Python sampler")
    p.add_argument("grammar", help="the .lsys file")
    p.add_argument("-o", "--out", type=argtypes.path, default=".",
                   help="output folder (default: current)")
    p.set_defaults(handler=cmd_compile)

    p = subparsers.add_parser("check", help="check a .lsys grammar and list its sites")
    p.add_argument("grammar", help="the .lsys file")
    p.set_defaults(handler=cmd_check)

    p = subparsers.add_parser("sample", help="draw one forward sample of a grammar's prior")
    p.add_argument("grammar", help=GRAMMAR_HELP)
    p.add_argument("--seed", type=argtypes.seed, default=0, help="random seed (default 0)")
    p.add_argument("-o", "--out", required=True, type=argtypes.path,
                   help="image to write (.png or .svg)")
    p.add_argument("--size", type=argtypes.render_size, default=512,
                   help=f"image size in pixels (default 512, at most {argtypes.MAX_RENDER_SIZE})")
    argtypes.add_max_modules(p)
    p.set_defaults(handler=cmd_sample)


def check_file(path: str) -> str:
    """`path`, when it names a file; else a one-line error."""
    if Path(path).is_dir():
        raise NgpmError(f"{path}: is a folder, not a grammar file")
    if not Path(path).is_file():
        raise NgpmError(f"{path}: no such grammar file")
    return path


def load(path: str) -> CompiledGrammar:
    return compile_grammar(Path(check_file(path)), filename=path)


def cmd_compile(args: argparse.Namespace) -> int:
    from ngpm_compiler.cli.outpaths import check_output_folder

    check_output_folder(args.out)
    compiled = load(args.grammar)
    sampler, sites = write_compiled(compiled, args.out)
    print(f"{args.grammar}: wrote {sampler} and {sites} ({len(compiled.sites)} sites)")
    return 0


def site_table(compiled: CompiledGrammar) -> list[str]:
    rows = [("#", "id", "kind", "prior", "where")]
    for s in compiled.sites:
        prior = s.source if s.probs is None else "(" + ", ".join(f"{p:.3g}" for p in s.probs) + ")"
        rows.append((str(s.index), s.id, s.kind, prior, f"line {s.line}:{s.col}"))
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    return ["  " + "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=False)) + "  " + r[4]
            for r in rows]


def cmd_check(args: argparse.Namespace) -> int:
    compiled = load(args.grammar)
    print(f"{args.grammar}: ok, {len(compiled.sites)} sites")
    if compiled.sites:
        print("\n".join(site_table(compiled)))
    return 0


def cmd_sample(args: argparse.Namespace) -> int:
    from ngpm_runtime.image.render import save_render
    from ngpm_runtime.inference.smc import forward

    suffix = Path(args.out).suffix.lower()
    if suffix not in (".png", ".svg"):
        raise NgpmError(f"{args.out}: the output must be a .png or .svg file")
    program = (load_grammar(check_file(args.grammar)) if args.grammar.endswith(".py")
               else load(args.grammar).program())
    particle = forward(program, seed=args.seed, max_modules=args.max_modules)
    prims = list(particle.primitives)
    if program.dim == 3:  # until 3D outputs: the picture seen from +Z
        from ngpm_runtime.geometry.turtle3d import project_xy

        save_render(project_xy(prims), args.out, viewport=program.viewport, size=args.size)
    else:
        save_render(prims, args.out, viewport=program.viewport, size=args.size)
    print(f"{args.grammar}: seed {args.seed}, {len(prims)} primitives, "
          f"log prior {particle.log_prior:.3f}, status {particle.status} -> {args.out}")
    note = argtypes.limit_note(particle, program, args.max_modules)
    if note:
        print(note)
    return 0
