"""`ngpmc compile`, `ngpmc check` and `ngpmc sample`: grammar commands."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from ngpm_runtime.errors import NgpmError, printable

from ngpm_compiler.cli import argtypes
from ngpm_compiler.language.compile import (
    CompiledGrammar,
    compile_grammar,
    load_grammar,
    write_compiled,
)

# The help of every argument that takes a grammar, .lsys or generated (load_grammar).
GRAMMAR_HELP = (
    "the .lsys file, or a *_sampler.py written by `ngpmc compile`: that file is "
    "Python and runs when loaded, so give only samplers you trust (ngpm refuses "
    "other .py files without running them)"
)


CHECK_TARGETS_HELP = (
    "a folder of 2D targets: grow into 3 of them with 600 unguided particles (as ngpmc "
    "learn does before its traces; a few seconds; default: none)"
)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser("compile", help="compile a .lsys grammar into a Python sampler")
    p.add_argument("grammar", help="the .lsys file")
    p.add_argument(
        "-o", "--out", type=argtypes.path, default=".", help="output folder (default: current)"
    )
    p.set_defaults(handler=cmd_compile)

    p = subparsers.add_parser(
        "check",
        help="check a .lsys grammar, list its sites and estimate its cost",
        description="Check a grammar and list its sites; then, from forward samples (a few "
        "seconds), the primitives per sample, the share of samples stopped by a "
        "cap, the time of one 600-particle SMC run, a proposed 'viewport:' line "
        "when the grammar has none, and a warning naming the rule when chains "
        "fork more than once per generation on average and samples run to a cap. "
        "With --targets, what unguided SMC reaches on a few of those targets, and a "
        "warning when it is too little for a guide to learn from.",
    )
    p.add_argument("grammar", help="the .lsys file")
    p.add_argument("--targets", type=argtypes.path, metavar="DIR", help=CHECK_TARGETS_HELP)
    p.add_argument(
        "--no-samples",
        action="store_true",
        help="only check and list the sites (no forward samples, no estimates)",
    )
    p.add_argument(
        "--samples",
        type=argtypes.integer(1, 1000),
        default=40,
        metavar="N",
        help="forward samples to draw at most (default 40, 1 to 1000; drawing "
        "stops after about 2 s)",
    )
    p.add_argument(
        "--seed", type=argtypes.seed, default=0, help="seed of the first forward sample (default 0)"
    )
    p.set_defaults(handler=cmd_check)

    p = subparsers.add_parser("sample", help="draw one forward sample of a grammar's prior")
    p.add_argument("grammar", help=GRAMMAR_HELP)
    p.add_argument("--seed", type=argtypes.seed, default=0, help="random seed (default 0)")
    p.add_argument(
        "-o",
        "--out",
        required=True,
        type=argtypes.path,
        help="file to write: a picture (.png or .svg); for a 3D grammar a mesh "
        "(.glb, .obj with its .mtl, .ply) or a shaded .png",
    )
    p.add_argument(
        "--size",
        type=argtypes.render_size,
        default=512,
        help=f"image size in pixels (default 512, at most {argtypes.MAX_RENDER_SIZE})",
    )
    p.add_argument(
        "--png",
        type=argtypes.output_file(".png"),
        metavar="PATH",
        help="3D grammars: also write a shaded picture of the mesh (default: none)",
    )
    p.add_argument(
        "--gif",
        type=argtypes.output_file(".gif"),
        metavar="PATH",
        help="3D grammars: also write a turntable GIF, 24 frames of half --size (default: none)",
    )
    p.add_argument(
        "--view",
        type=view,
        metavar="AZ,EL",
        help="3D grammars: the pictures' view, azimuth and elevation in degrees "
        "(default 45,20; 0,0 looks from +Z, as the 2D render)",
    )
    argtypes.add_max_modules(p)
    p.set_defaults(handler=cmd_sample)


def view(text: str) -> tuple[float, float]:
    """An argparse type: AZ,EL in degrees (elevation from -90 to 90)."""
    parts = text.split(",")
    try:
        az, el = (float(x) for x in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected AZ,EL in degrees, like 45,20, got {text!r}"
        ) from None
    if not (math.isfinite(az) and -90 <= el <= 90):
        raise argparse.ArgumentTypeError(
            f"the azimuth must be a number and the elevation from -90 to 90, got {text!r}"
        )
    return az, el


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
    return [
        "  " + "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=False)) + "  " + r[4]
        for r in rows
    ]


def cmd_check(args: argparse.Namespace) -> int:
    from ngpm_compiler.evaluation.diagnose import (
        diagnose,
        hint_lines,
        sample_lines,
        warning_lines,
    )

    compiled = load(args.grammar)
    print(f"{args.grammar}: ok, {len(compiled.sites)} sites")
    if compiled.sites:
        print("\n".join(site_table(compiled)))
    diag = diagnose(compiled, samples=0 if args.no_samples else args.samples, seed=args.seed)
    hints = hint_lines(diag, compiled.checked)
    for line in [*sample_lines(diag), *warning_lines(diag), *hints]:
        print(line, flush=True)
    if args.targets:
        print("\n".join(reach_check(args.grammar, diag, args.targets)), flush=True)
    return 0


def reach_check(filename: str, diag: Any, folder: str) -> list[str]:
    """`check --targets`: what unguided SMC reaches on a few targets of `folder` (its
    line, and the warning when low)."""
    from dataclasses import replace

    from ngpm_compiler.evaluation.diagnose import (
        REACH_TARGETS,
        reach_line,
        reach_seen,
        reachability,
    )
    from ngpm_compiler.evaluation.heldout import load_sets

    program = diag.program
    if program.dim != 2:
        raise NgpmError(f"--targets {folder}: a 3D grammar grows into volumes; give a 2D one")
    viewport = program.viewport or diag.viewport
    if viewport is None:
        raise NgpmError(f"--targets: {filename} has no 'viewport:' line to draw into targets")
    if not Path(folder).is_dir():
        raise NgpmError(f"--targets {folder}: no such folder of targets")
    program = replace(program, viewport=viewport)
    targets = load_sets({"t": folder}, REACH_TARGETS, program)["t"]
    if not targets:
        raise NgpmError(f"--targets {folder}: holds no targets")
    r = reachability(program, targets)
    out = [
        f"unguided SMC, {r.n} particles, on {len(targets)} targets of {printable(folder)}: "
        f"similarity {r.similarity:.3f}; {reach_seen(r.drawn, r.covered, r.ink, r.dim)}"
    ]
    return [*out, reach_line(r, filename)] if r.low else out


MESH_SUFFIXES = (".glb", ".obj", ".ply")


def cmd_sample(args: argparse.Namespace) -> int:
    from ngpm_runtime.inference.smc import forward

    suffix = Path(args.out).suffix.lower()
    if suffix not in (".png", ".svg", *MESH_SUFFIXES):
        raise NgpmError(
            f"{args.out}: the output must be a .png or .svg file (or .glb, .obj, "
            ".ply for a 3D grammar)"
        )
    program = (
        load_grammar(check_file(args.grammar))
        if args.grammar.endswith(".py")
        else load(args.grammar).program()
    )
    three_d = getattr(program, "dim", 2) == 3
    check_sample_outputs(args, suffix, three_d)
    particle = forward(program, seed=args.seed, max_modules=args.max_modules)
    prims = list(particle.primitives)
    if three_d:
        written = save_3d(args, prims)
    else:
        from ngpm_runtime.image.render import save_render

        save_render(prims, args.out, viewport=program.viewport, size=args.size)
        written = args.out
    print(
        f"{args.grammar}: seed {args.seed}, {len(prims)} primitives, "
        f"log prior {particle.log_prior:.3f}, status {particle.status} -> {written}"
    )
    note = argtypes.limit_note(particle, program, args.max_modules)
    if note:
        print(note)
    return 0


def check_sample_outputs(args: argparse.Namespace, suffix: str, three_d: bool) -> None:
    """One-line errors for outputs the grammar's dimension has no use for."""
    if not three_d:
        if suffix in MESH_SUFFIXES:
            raise NgpmError(
                f"{args.out}: mesh output ({', '.join(MESH_SUFFIXES)}) is for 3D "
                f"grammars; {args.grammar} is 2D (write .png or .svg)"
            )
        extra = [f"--{k}" for k in ("png", "gif", "view") if getattr(args, k) is not None]
        if extra:
            raise NgpmError(f"{' and '.join(extra)}: for 3D grammars; {args.grammar} is 2D")
    elif suffix == ".svg":
        raise NgpmError(
            f"{args.out}: SVG output is for 2D grammars; {args.grammar} is 3D "
            "(write .glb, .obj, .ply, or a .png picture: --view 0,0 looks from +Z)"
        )


def save_3d(args: argparse.Namespace, prims: list) -> str:
    """The mesh of a 3D sample, saved to -o, --png and --gif; returns what was written."""
    from ngpm_runtime.geometry.mesh import mesh_from_primitives

    mesh = mesh_from_primitives(prims)
    done = [args.out]
    mesh.save(args.out, size=args.size, view=args.view)
    for path in (args.png, args.gif):
        if path is not None:
            size = args.size if path.lower().endswith(".png") else max(1, args.size // 2)
            mesh.save(path, size=size, view=args.view)
            done.append(path)
    return f"{', '.join(done)} ({len(mesh.faces)} triangles)"
