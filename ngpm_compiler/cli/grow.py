"""`ngpmc grow`: grow a grammar (by default the bundled vines, with its guide) into a target
image with SMC, and write the best particle's render (PNG or SVG, optionally an animation).
A 3D target (a mesh) or a 3D grammar grows in 3D (grow3d.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ngpm_runtime.errors import NgpmError
from ngpm_runtime.program import require_2d

from ngpm_compiler.cli import argtypes, grow3d
from ngpm_compiler.cli.grammar import GRAMMAR_HELP
from ngpm_compiler.cli.grow_common import (
    LOW_SIMILARITY,
    SIMILARITY_SCALE,
    _grow_guide,
    _step_ticks,
)

GROW_SUFFIX = "_grown"  # ngpmc grow heart.png writes heart_grown.png by default


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "grow",
        help="grow a vine (or any grammar) into a picture with SMC",
        description="Grow a grammar into a target image with SMC. With no --grammar it grows "
        "the bundled vines model, guided by the bundled pretrained guide. It "
        f"prints the similarity of the best particle: {SIMILARITY_SCALE}.",
    )
    p.add_argument(
        "image",
        nargs="?",
        metavar="IMAGE",
        help="target image; a .txt sidecar beside it gives the start "
        "(`x y` then `dx dy`), else it is found automatically; or a 3D target: a mesh "
        "(.obj, .stl, .ply, .glb) or .npz, grown by a 3D grammar (default: the bundled "
        "vines3d and its guide) into -o tree.glb",
    )
    p.add_argument("--grammar", help=f"{GRAMMAR_HELP} (default: the bundled vines model)")
    p.add_argument(
        "--guide",
        type=argtypes.path,
        help="guide .onnx, or 'none' for unguided SMC (default: the bundled guide "
        "for the grammar and likelihood, if any)",
    )
    p.add_argument(
        "-N",
        "--particles",
        type=argtypes.particles,
        default=10,
        help=f"particles (default 10, at most {argtypes.MAX_PARTICLES})",
    )
    p.add_argument("--seed", type=argtypes.seed, default=0, help="seed (default 0)")
    argtypes.add_target_size(p)
    p.add_argument(
        "--likelihood",
        choices=("shape", "circuit"),
        default="shape",
        help="shape: match the image (default); circuit: the paper's circuit-like "
        "density, guided by the bundled circuit guide for vines (the image, if any, only "
        "gives the start and size; without one the vine starts at the bottom middle)",
    )
    p.add_argument(
        "-o",
        "--out",
        type=argtypes.path,
        help="render of the best particle, .png or .svg (default: "
        f"IMAGE{GROW_SUFFIX}.png in the current folder)",
    )
    p.add_argument(
        "--svg",
        nargs="?",
        const="",
        metavar="PATH",
        help="also write an SVG (default path: the -o file with .svg)",
    )
    p.add_argument(
        "--steps-gif",
        nargs="?",
        const="",
        metavar="PATH",
        help="also write an animation of the growth (default path: the -o file with .gif)",
    )
    argtypes.add_max_modules(p)
    grow3d.add_arguments(p)
    p.set_defaults(handler=cmd_grow)


def _grow_inputs(args: argparse.Namespace) -> tuple[str | None, str | None]:
    """(grammar or None for the bundled vines, image or None) from the command line."""
    grammar, image = args.grammar, args.image
    if image is not None and Path(image).is_dir():
        raise NgpmError(
            f"{image} is a folder: grow wants one target image "
            "(ngpmc grow IMAGE -o vine.png), so run it once per image"
        )
    if image is not None and Path(image).suffix.lower() in (".lsys", ".py"):
        raise NgpmError(f"{image} is a grammar, not an image: ngpmc grow IMAGE --grammar {image}")
    return grammar, image


def _grow_outputs(args: argparse.Namespace) -> tuple[Path, Path | None, Path | None]:
    """(render, svg, gif) paths, checked before any work is done."""
    from ngpm_compiler.cli.outpaths import check_output_file

    stem = Path(args.image).stem if args.image else "circuit"
    out = Path(args.out) if args.out else Path(f"{stem}{GROW_SUFFIX}.png")
    if out.suffix.lower() not in (".png", ".svg"):
        raise NgpmError(f"{out}: the output must be a .png or .svg file")

    def derived(value: str | None, suffix: str, flag: str) -> Path | None:
        if value is None:
            return None
        path = Path(value) if value else out.with_suffix(suffix)
        if path.suffix.lower() != suffix:
            raise NgpmError(f"{path}: {flag} writes a {suffix} file")
        return path

    paths = (
        out,
        derived(args.svg, ".svg", "--svg"),
        derived(args.steps_gif, ".gif", "--steps-gif"),
    )
    for path in paths:
        if path is not None:
            check_output_file(path)
    return paths


def cmd_grow(args: argparse.Namespace) -> int:
    from ngpm_runtime import bundled
    from ngpm_runtime.image.targets import load_target

    from ngpm_compiler.language.compile import load_grammar

    grammar, image = _grow_inputs(args)
    loaded = None
    if grammar is not None and Path(grammar).is_file():
        loaded = load_grammar(grammar)
    if grow3d.wants_3d(args, image, loaded):
        return grow3d.cmd_grow3d(args, image, loaded)
    if image is None and args.likelihood == "shape":
        raise NgpmError("give a target image: ngpmc grow IMAGE -o vine.png")
    out, svg, gif = _grow_outputs(args)
    if grammar is None:
        program = bundled.bundled_program()
    else:
        if loaded is None:
            raise NgpmError(f"{grammar}: no such grammar file")
        program = loaded
    require_2d(program, "growing into a picture")  # before the target and the guide
    target = load_target(image, size=args.size) if image is not None else None
    fit = target.fit_note() if target is not None else None
    if fit:
        print(f"warning: {fit}")
    guide = _grow_guide(args.guide, program, args.likelihood)
    if guide is not None and guide.fallback_sites:
        ids = ", ".join(program.sites[i].id for i in guide.fallback_sites)
        print(f"guide: {len(guide.fallback_sites)} sites unseen in training use the prior: {ids}")
    from ngpm_runtime.grow import grow

    from ngpm_compiler.progress import Progress

    with Progress("grow", unit="step", delay=1.0, leave=False) as bar:
        res = grow(
            program,
            target,
            guide,
            args.particles,
            args.seed,
            args.likelihood,
            observers=(_step_ticks(bar),),
            max_modules=args.max_modules,
        )
    kind = "guided" if guide else "unguided"
    name = target.name if target is not None else program.name
    score = (
        f"similarity {res.similarity:.3f}"
        if args.likelihood == "shape"
        else f"circuit score {res.similarity:.3f} (log-likelihood "
        f"{res.smc.best.log_likelihood:.2f})"
    )
    print(
        f"{name}: {score}, {res.particles} particles ({kind}), {res.seconds:.2f} s, "
        f"{len(res.primitives)} primitives"
    )
    if args.likelihood == "shape" and res.similarity < LOW_SIMILARITY:
        print(f"similarity: {SIMILARITY_SCALE}")
    if guide is not None:
        print(f"guide: {guide.path}")
    note = argtypes.limit_note(res.smc.best, program, args.max_modules)
    if note:
        print(note)
    from ngpm_runtime.image.render import save_render, save_steps_gif

    mask = target.mask if target is not None else None
    for path in (out, svg):
        if path is not None:
            save_render(res.primitives, path, viewport=program.viewport, target_mask=mask)
            print(f"wrote {path}")
    if gif is not None:
        assert program.viewport is not None  # grow() refuses a grammar without one
        save_steps_gif(res.primitives, gif, program.viewport, mask)
        print(f"wrote {gif} (growth animation)")
    return 0
